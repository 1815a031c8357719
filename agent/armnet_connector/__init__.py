"""The connector sidecar: the only process that touches a cell's serial bus and cameras.

It serves ``robot.sock`` and ``operator.sock`` (runtime/PROTOCOL.md) against the
real LeRobot classes, behind an allow-list, a safety interlock and the job's
deadline. ``Connector`` is the in-process API; ``armnet connector`` the command.
"""

from __future__ import annotations

__version__ = "0.1.0"

from armnet_core.cell_completion import CompletionConfig  # noqa: E402

from .config import ArmConfig, CameraConfig, ConnectorConfig, load_config  # noqa: E402
from .connector import Connector  # noqa: E402
from .inputs import CompletionMonitor, LocalOperatorInputs, NeverComplete, OperatorInputs  # noqa: E402

__all__ = [
    "ArmConfig",
    "CameraConfig",
    "CompletionConfig",
    "CompletionMonitor",
    "Connector",
    "ConnectorConfig",
    "LocalOperatorInputs",
    "NeverComplete",
    "OperatorInputs",
    "load_config",
    # Modules other packages import (the node agent's probes, telemetry, inputs and completion-file check,
    # the launch library's cells).
    "agent_inputs",
    "block_read",
    "calibration_check",
    "cell",
    "classifier_scorer",
    "config",
    "fast_exit",
    "hardware",
    "host_files",
    "inputs",
    "interlock",
    "observer",
    "ratelog",
    "reply_window",
    "service_scorer",
    "telemetry",
    "telemetry_decode",
    "warm_imports",
]

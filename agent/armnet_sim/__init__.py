"""The cell simulator: Feetech STS3215 servo buses on pseudo-terminals, plus cameras.

The real ``scservo_sdk`` and LeRobot's ``FeetechMotorsBus`` talk to it unmodified
through ``SimulatedArm.port``. Pure pieces (``protocol``, ``control_table``,
``physics``, ``servo``, ``bus_model``, ``render``) never do I/O; ``pty_server``,
``sim_bus``, ``arm`` and ``camera`` own the threads; ``process`` runs a cell in
a child process. ``SimulatedCamera`` is imported lazily because it needs LeRobot.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from .arm import DEGREES, RANGE_0_100, RANGE_M100_100, SO101_MOTORS, MotorSpec, SimulatedArm
from .calibration import (
    CalibrationError,
    MotorCalibration,
    builtin_calibration,
    dump_calibration,
    load_calibration,
    write_calibration,
)
from .physics import PhysicsParams
from .presets import PRESETS, SimulatedCell, build_cell
from .process import RemoteArm, SimulatedCellProcess, SimulatorProcessError
from .protocol import ErrorBit
from .servo import ServoFaults
from .sim_bus import SimulatedBus

if TYPE_CHECKING:
    from .camera import SimulatedCamera

__all__ = [
    "DEGREES",
    "PRESETS",
    "RANGE_0_100",
    "RANGE_M100_100",
    "SO101_MOTORS",
    "CalibrationError",
    "ErrorBit",
    "MotorCalibration",
    "MotorSpec",
    "PhysicsParams",
    "RemoteArm",
    "ServoFaults",
    "SimulatedArm",
    "SimulatedBus",
    "SimulatedCamera",
    "SimulatedCell",
    "SimulatedCellProcess",
    "SimulatorProcessError",
    "build_cell",
    "builtin_calibration",
    "dump_calibration",
    "load_calibration",
    "write_calibration",
    # Modules other packages import (the connector's simulated cameras, the launch library's simulated cells).
    "calibration",
    "camera",
    "presets",
    "process",
    "render",
]


def __getattr__(name: str) -> Any:
    if name == "SimulatedCamera":
        from .camera import SimulatedCamera

        return SimulatedCamera
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

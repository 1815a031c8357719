"""armnet's teleop relay as a LeRobot teleoperator (``armnet_relay``), for LeRobot's own recording.

Imports LeRobot: a job imports it when it records, never the SDK at start-up.
"""

from __future__ import annotations

from armnet_runtime.lerobot.teleop.config import RELAY_TYPE, ArmnetRelayConfig
from armnet_runtime.lerobot.teleop.relay import ArmnetRelay, merge_action

__all__ = ["RELAY_TYPE", "ArmnetRelay", "ArmnetRelayConfig", "merge_action"]

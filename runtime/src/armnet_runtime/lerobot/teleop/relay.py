"""``ArmnetRelay``: a LeRobot ``Teleoperator`` whose leader arm is the cell's teleop stream.

A LeRobot recording loop asks its teleoperator for an action each tick. Here the
answer is the freshest action the cell's connector holds from the operator
(``Cell.get_teleop_action``: the latest value wins, nothing queues), laid over the
last action sent, so a joint the operator has not moved keeps its value and a lost
channel holds position instead of ending the recording.
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

from lerobot.teleoperators.teleoperator import Teleoperator

from armnet_runtime.context import Cell
from armnet_runtime.lerobot.teleop.config import RELAY_TYPE, ArmnetRelayConfig

_POSITION_SUFFIX = ".pos"


def merge_action(last: dict[str, float], received: dict[str, float] | None) -> dict[str, float]:
    """``last`` with each of its keys the operator sent replaced; other keys are ignored.

    The operator may name a joint as the robot does (``"elbow_flex.pos"``) or bare
    (``"elbow_flex"``, as a leader arm's bus reads it). Pure.
    """
    action = dict(last)
    if not received:
        return action
    for key in action:
        if key in received:
            action[key] = received[key]
        elif key.endswith(_POSITION_SUFFIX) and key.removesuffix(_POSITION_SUFFIX) in received:
            action[key] = received[key.removesuffix(_POSITION_SUFFIX)]
    return action


class ArmnetRelay(Teleoperator):  # type: ignore[misc]  # LeRobot ships no type information
    """The operator's leader arm, relayed by the cell: actions in, no feedback, nothing to calibrate."""

    config_class = ArmnetRelayConfig
    name = RELAY_TYPE

    def __init__(self, config: ArmnetRelayConfig) -> None:
        if not config.hold:
            raise ValueError(
                "ArmnetRelayConfig.hold is empty: name every action key of the robot with the value to "
                "hold until the operator moves it, e.g. the follower's pose from robot.get_observation()"
            )
        if config.calibration_dir is None:  # nothing to calibrate; keep LeRobot's empty folder out of the output
            config.calibration_dir = Path(tempfile.gettempdir()) / "armnet-relay-calibration"
        super().__init__(config)
        self.config = config
        self._last = {key: float(value) for key, value in config.hold.items()}
        self._cell: Cell | None = None

    @property
    def action_features(self) -> dict[str, type]:
        return {key: float for key in self._last}

    @property
    def feedback_features(self) -> dict[str, type]:
        return {}

    @property
    def is_connected(self) -> bool:
        return self._cell is not None

    def connect(self, calibrate: bool = True) -> None:
        self._cell = Cell(operator_call_endpoint=self.config.operator_call_endpoint,
                          local_control_endpoint=self.config.local_control_endpoint)

    @property
    def is_calibrated(self) -> bool:
        return True

    def calibrate(self) -> None:
        """Nothing to do: the operator's leader arm is calibrated where it stands."""

    def configure(self) -> None:
        """Nothing to do: no device of its own."""

    def get_action(self) -> dict[str, float]:
        if self._cell is None:
            raise RuntimeError("ArmnetRelay is not connected: call connect() first")
        self._last = merge_action(self._last, self._cell.get_teleop_action())
        return dict(self._last)

    def send_feedback(self, feedback: dict[str, Any]) -> None:
        """Feedback to the leader arm is not relayed: the operator's device runs open loop."""

    def disconnect(self) -> None:
        self._cell = None

"""LeRobot's own robot classes, unmodified, under ``armnet run`` on the simulated cell.

``SO101Follower`` and ``BiSOFollower`` import ``lerobot.processor`` (torchvision, av,
einops, pillow): these tests fail when the environment lacks what the robot
classes need, and show that LeRobot's ``max_relative_target`` (the cell's safety
limit) clamps the steps before the connector sees them.
"""

from __future__ import annotations

import pytest
from armnet_core import JobStatus

from e2e.test_local_run import ARRIVED, EXAMPLES, InProcessRun

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(600)]


def test_the_so101_follower_example_reaches_its_target_through_lerobots_clamping() -> None:
    run = InProcessRun(str(EXAMPLES / "so101_follower.py"), "--embodiment", "lerobot/so-101", "--timeout", "300")
    result = run()
    assert result.status is JobStatus.SUCCEEDED, f"{result}\n{result.stderr}"
    value = result.return_value
    assert value["frames"] == {"front": [480, 640, 3]}
    for joint, target in value["target"].items():
        assert abs(value["reached"][joint] - target) <= ARRIVED, joint
        assert abs(run.joints["arm"][joint] - target) <= ARRIVED, joint  # the simulator agrees


def test_the_bimanual_follower_example_moves_both_arms() -> None:
    run = InProcessRun(str(EXAMPLES / "bimanual_follower.py"), "--preset", "bimanual_so101", "--timeout", "300")
    result = run()
    assert result.status is JobStatus.SUCCEEDED, f"{result}\n{result.stderr}"
    value = result.return_value
    for key, target in value["target"].items():
        side, joint = key.removesuffix(".pos").split("_", 1)
        assert abs(value["reached"][key] - target) <= ARRIVED, key
        assert abs(run.joints[side][joint] - target) <= ARRIVED, key

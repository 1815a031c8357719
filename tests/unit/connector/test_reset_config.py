"""A cell's ``reset`` settings: a scripted reset that cannot work is refused with what to fix."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from armnet_connector import ConnectorConfig, LocalOperatorInputs
from armnet_connector.cell import CellState
from armnet_core.cell_completion import ResetConfig, reset_problem, split_pose
from pydantic import ValidationError

from tests.unit.connector.conftest import so101_config

pytestmark = pytest.mark.unit

COMPLETION = {
    "camera": "front", "region": {"left": 0.7, "top": 0.1, "width": 0.1, "height": 0.1},
    "colour": {"hueMin": 170, "hueMax": 8},
}


def a_reset(**overrides: Any) -> dict[str, Any]:
    data: dict[str, Any] = {"mode": "Scripted", "poses": [{"shoulder_lift": -30, "elbow_flex": 20}]}
    data.update(overrides)
    return data


def test_a_scripted_reset_loads_in_camel_case_with_its_defaults() -> None:
    reset = ResetConfig.model_validate(a_reset())
    assert (reset.scripted, reset.attempts, reset.settle_seconds) == (True, 3, 1.0)
    assert ResetConfig.model_validate({}).mode == "Operator"


@pytest.mark.parametrize(("why", "overrides", "message"), [
    ("an unknown mode", {"mode": "Robot"}, "is not a reset mode"),
    ("no poses", {"poses": []}, "needs reset.poses"),
    ("poses without Scripted", {"mode": "Operator"}, "set mode: Scripted"),
    ("17 poses", {"poses": [{"elbow_flex": 0}] * 17}, "at most 16"),
    ("an empty pose", {"poses": [{}]}, "non-empty mapping"),
    ("a NaN angle", {"poses": [{"elbow_flex": float("nan")}]}, "finite number"),
    ("a string angle", {"poses": [{"elbow_flex": "up"}]}, "must be a number"),
    ("no attempt", {"attempts": 0}, "give 1 to 10"),
    ("eleven attempts", {"attempts": 11}, "give 1 to 10"),
    ("a negative settle", {"settleSeconds": -1}, "give 0 to 30 seconds"),
])
def test_a_reset_that_cannot_run_is_refused_saying_what_to_fix(why: str, overrides: dict[str, Any],
                                                                message: str) -> None:
    with pytest.raises(ValidationError, match=message):
        ResetConfig.model_validate(a_reset(**overrides))


def test_a_scripted_reset_needs_the_completion_monitor_that_judges_it() -> None:
    problem = reset_problem(ResetConfig.model_validate(a_reset()), None, ["arm"])
    assert problem is not None and "needs the cell's completion monitor (spec.completion)" in problem
    with pytest.raises(ValidationError, match="add spec.completion"):
        so101_config(None, reset=a_reset())
    assert so101_config(None, reset=a_reset(), completion=COMPLETION).reset == ResetConfig.model_validate(a_reset())


def test_an_operator_reset_needs_no_monitor() -> None:
    assert reset_problem(ResetConfig.model_validate({"mode": "Operator"}), None, ["arm"]) is None


def test_a_pose_names_joints_of_the_cell_s_arm() -> None:
    from armnet_core.cell_completion import CompletionConfig

    completion = CompletionConfig.model_validate(COMPLETION)
    bad = ResetConfig.model_validate(a_reset(poses=[{"elbow": 10}]))
    problem = reset_problem(bad, completion, ["arm"])
    assert problem is not None and "'elbow' is not a joint of this cell" in problem
    with pytest.raises(ValidationError, match="not a joint of this cell"):
        so101_config(None, reset=a_reset(poses=[{"elbow": 10}]), completion=COMPLETION)


def test_a_pose_beyond_a_turn_or_an_open_gripper_is_refused() -> None:
    from armnet_core.cell_completion import CompletionConfig

    completion = CompletionConfig.model_validate(COMPLETION)
    turn = reset_problem(ResetConfig.model_validate(a_reset(poses=[{"elbow_flex": 200}])), completion, ["arm"])
    assert turn == "reset.poses[0].elbow_flex is 200; give -180 to 180 degrees"
    grip = reset_problem(ResetConfig.model_validate(a_reset(poses=[{"gripper": 120}])), completion, ["arm"])
    assert grip == "reset.poses[0].gripper is 120; give 0 (closed) to 100 (open)"


def test_a_bimanual_pose_names_each_joint_with_its_arm() -> None:
    assert split_pose({"left_elbow_flex": 10, "right_gripper": 50}, ["left", "right"]) == {
        "left": {"elbow_flex": 10.0}, "right": {"gripper": 50.0}}
    with pytest.raises(ValueError, match="'elbow_flex' is not a joint of this cell"):
        split_pose({"elbow_flex": 10}, ["left", "right"])


def test_a_pose_outside_the_arm_s_calibrated_range_leaves_every_reset_to_the_person(tmp_path: Path) -> None:
    # shoulder_pan's calibrated range is raw 780..3320: 179 degrees from its middle is raw 4086.
    config = so101_config(None, reset=a_reset(poses=[{"shoulder_pan": 179}]), completion=COMPLETION)
    cell = CellState(config, LocalOperatorInputs())
    assert cell.reset_unusable == (
        "reset.poses[0]: shoulder_pan 179 is raw 4086, outside arm 'arm''s calibrated range [780, 3320]; "
        "give a value inside it"
    )
    assert cell.reset_targets == []


def test_the_poses_are_converted_to_raw_ticks_as_the_arm_s_bus_converts_a_job_s_goal() -> None:
    config = so101_config(None, reset=a_reset(poses=[{"elbow_flex": 0, "gripper": 100}]), completion=COMPLETION)
    cell = CellState(config, LocalOperatorInputs())
    assert cell.reset_unusable is None
    assert cell.reset_targets == [{"arm": {"elbow_flex": (870 + 3090) // 2, "gripper": 3430}}]


def test_a_connector_config_of_another_kind_keeps_working() -> None:
    assert ConnectorConfig.model_validate({"arms": {"arm": {"port": "/dev/null"}}}).reset is None

"""The safety report's largest requested step: per motor, by size, and it only ever grows."""

from __future__ import annotations

import pytest
from armnet_connector.report import SafetyRecorder

pytestmark = pytest.mark.unit


def test_the_largest_step_of_each_motor_is_kept_by_its_size() -> None:
    recorder = SafetyRecorder("clamp")
    recorder.record_steps({"elbow": 2.0, "gripper": -3.0})
    recorder.record_steps({"elbow": -5.0, "gripper": 1.0})
    assert recorder.snapshot().largest_requested_step == {"elbow": 5.0, "gripper": 3.0}


def test_smaller_steps_after_a_large_one_leave_it_in_the_report() -> None:
    recorder = SafetyRecorder("clamp")
    recorder.record_steps({"elbow": 7.5})
    for _ in range(3):
        recorder.record_steps({"elbow": 0.5})
    assert recorder.snapshot().largest_requested_step == {"elbow": 7.5}


def test_a_new_motor_among_smaller_steps_is_recorded() -> None:
    recorder = SafetyRecorder("clamp")
    recorder.record_steps({"elbow": 7.5})
    recorder.record_steps({"elbow": 0.5, "wrist_roll": 0.25})
    assert recorder.snapshot().largest_requested_step == {"elbow": 7.5, "wrist_roll": 0.25}

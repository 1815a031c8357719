"""A cell's health conditions from probe results: each false one says why and what to do."""

from __future__ import annotations

from datetime import UTC, datetime

import pytest
from armnet_node.health import ArmProbe, CellProbe, cell_health, merge_conditions

pytestmark = pytest.mark.unit

ALL_ANSWER = {"shoulder_pan": (1, 777), "gripper": (6, 777)}


def arm(**overrides: object) -> ArmProbe:
    base: dict[str, object] = {"port": "/dev/ttyACM0", "answers": ALL_ANSWER,
                               "calibration_file": "/cal/f.json", "calibration_exists": True}
    base.update(overrides)
    return ArmProbe(**base)  # type: ignore[arg-type]


def conditions(probe: CellProbe) -> dict[str, tuple[str, str, str]]:
    return {c.type: (c.status, c.reason, c.message) for c in cell_health(probe)}


def test_a_healthy_cell_has_all_five_conditions_true() -> None:
    found = conditions(CellProbe(arms={"arm": arm()}, cameras={"front": None}))
    assert set(found) == {"AgentConnected", "HardwareReady", "CalibrationPresent", "CamerasReady", "InterlockClear"}
    assert {status for status, _, _ in found.values()} == {"True"}


LOST = ("DeviceLost", "arm arm's serial port: /dev/ttyACM0 does not exist (it was present and vanished); plug it back")


def test_lost_devices_make_hardware_not_ready_with_the_watchs_reason_before_any_servo_fact() -> None:
    silent = arm(answers={"shoulder_pan": (1, None)})
    status, reason, message = conditions(CellProbe(arms={"arm": silent}, devices_lost=LOST))["HardwareReady"]
    assert (status, reason, message) == ("False", *LOST)


def test_a_silent_servo_is_named_by_motor_and_id() -> None:
    answers = {"shoulder_pan": (1, 777), "elbow_flex": (3, None)}
    status, reason, message = conditions(CellProbe(arms={"arm": arm(answers=answers)}))["HardwareReady"]
    assert (status, reason) == ("False", "ServoNotResponding")
    assert "elbow_flex (id 3)" in message


def test_a_servo_of_the_wrong_model_is_not_ready() -> None:
    answers = {"shoulder_pan": (1, 1060)}
    status, reason, _ = conditions(CellProbe(arms={"arm": arm(answers=answers)}))["HardwareReady"]
    assert (status, reason) == ("False", "WrongServoModel")


def test_a_calibration_missing_a_motor_is_incomplete() -> None:
    status, reason, message = conditions(
        CellProbe(arms={"arm": arm(calibration_missing=("gripper",))}))["CalibrationPresent"]
    assert (status, reason) == ("False", "CalibrationIncomplete")
    assert "gripper" in message and "lerobot-calibrate" in message


def test_an_absent_calibration_file_is_missing() -> None:
    status, reason, _ = conditions(CellProbe(arms={"arm": arm(calibration_exists=False)}))["CalibrationPresent"]
    assert (status, reason) == ("False", "CalibrationMissing")


def test_an_unreadable_camera_is_not_ready() -> None:
    status, reason, message = conditions(
        CellProbe(arms={"arm": arm()}, cameras={"front": "no frame in 2 s"}))["CamerasReady"]
    assert (status, reason) == ("False", "CameraUnreadable")
    assert "front" in message


def test_a_tripped_interlock_during_a_job_is_reported_from_the_connector() -> None:
    status, reason, message = conditions(
        CellProbe(arms={"arm": arm()}, interlock_trip="step 40 > limit 10 on shoulder_pan",
                  bus_held_by_job=True))["InterlockClear"]
    assert (status, reason) == ("False", "InterlockTripped")
    assert "shoulder_pan" in message


def test_a_transition_time_moves_only_when_the_status_changes() -> None:
    first = datetime(2026, 1, 1, tzinfo=UTC)
    later = datetime(2026, 1, 2, tzinfo=UTC)
    healthy = cell_health(CellProbe(arms={"arm": arm()}))
    merged = merge_conditions([], healthy, first)
    again = merge_conditions(merged, healthy, later)
    assert {c["lastTransitionTime"] for c in again} == {"2026-01-01T00:00:00Z"}
    broken = cell_health(CellProbe(arms={"arm": arm()}, devices_lost=LOST))
    changed = {c["type"]: c["lastTransitionTime"] for c in merge_conditions(again, broken, later)}
    assert changed["HardwareReady"] == "2026-01-02T00:00:00Z"
    assert changed["AgentConnected"] == "2026-01-01T00:00:00Z"


def test_servos_whose_eeprom_differs_from_the_calibration_file_make_calibration_false_naming_them() -> None:
    mismatch = "wrist_roll Homing_Offset holds 37, the cell's file says 0"
    status, reason, message = conditions(CellProbe(arms={"arm": arm(calibration_mismatches=(mismatch,))}))[
        "CalibrationPresent"]
    assert (status, reason) == ("False", "CalibrationMismatch")
    assert mismatch in message and "lerobot-calibrate" in message

"""What the agent publishes for the cell operator's page: subjects, the servo JSON, frame sizes, cadence."""

from __future__ import annotations

import dataclasses
import json

import pytest
from armnet_connector.telemetry_decode import ServoSample, decode_block
from armnet_node.telemetry_wire import (
    MAX_MOTORS,
    Cadence,
    camera_subject,
    monitor_payload,
    monitor_subject,
    scaled_size,
    servos_payload,
    servos_subject,
)

pytestmark = pytest.mark.unit


def test_subjects_name_the_cell_and_the_camera() -> None:
    assert servos_subject("cell-1") == "telemetry.cell-1.servos"
    assert camera_subject("cell-1", "front") == "telemetry.cell-1.camera.front"


@pytest.mark.parametrize("name", ["a.b", "*", ">", "has space", "", "x" * 64])
def test_a_name_that_is_not_one_subject_token_is_refused(name: str) -> None:
    with pytest.raises(ValueError, match="NATS subject token"):
        camera_subject("cell-1", name)


def test_the_servo_payload_carries_each_motors_three_readings_and_null_for_a_silent_one() -> None:
    payload = servos_payload(12.3456, "job", {"arm": {"gripper": ServoSample(2048, -7, 31), "wrist_roll": None}})
    assert json.loads(payload) == {"t": 12.346, "source": "job", "arms": {"arm": {"motors": {
        "gripper": {"position": 2048, "load": -7, "temperature": 31}, "wrist_roll": None}}}}


def test_an_arm_that_was_not_read_says_why() -> None:
    assert json.loads(servos_payload(0, "job", {"left": "busy"}))["arms"] == {"left": {"error": "busy"}}


def test_the_servo_payload_is_bounded_whatever_the_cell_holds() -> None:
    motors = {f"m{i}": ServoSample(i, 0, 30) for i in range(500)}
    body = json.loads(servos_payload(0, "idle", {"arm": motors, "other": "x" * 10_000}))
    assert len(body["arms"]["arm"]["motors"]) == MAX_MOTORS
    assert len(body["arms"]["other"]["error"]) == 200


def test_frames_are_scaled_down_to_the_published_width_keeping_their_aspect() -> None:
    assert scaled_size(640, 480) == (320, 240)
    assert scaled_size(1920, 1080) == (320, 180)


def test_a_small_frame_is_never_enlarged() -> None:
    assert scaled_size(160, 120) == (160, 120)


def runs(cadence: Cadence, times: tuple[float, ...]) -> tuple[list[bool], Cadence]:
    """Whether the action ran at each time, and the cadence after the last."""
    ran = []
    for t in times:
        due, cadence = cadence.due(t)
        ran.append(due)
    return ran, cadence


def test_a_cadence_runs_once_per_period() -> None:
    ran, _ = runs(Cadence.per_second(2), (0.0, 0.1, 0.49, 0.5, 0.7, 1.0))
    assert ran == [True, False, False, True, False, True]


def test_a_cadence_after_a_stall_restarts_from_now_instead_of_bursting() -> None:
    ran, cadence = runs(Cadence.per_second(4), (0.0, 10.0, 10.1))  # stalled for 40 periods
    assert ran == [True, True, False]
    assert cadence.wait_s(10.1) == pytest.approx(0.15)


def test_a_cadence_is_a_value_that_due_never_changes() -> None:
    cadence = Cadence.per_second(4)
    _, after = cadence.due(0.0)
    assert cadence.next_at == 0.0 and after.next_at == 0.25
    with pytest.raises(dataclasses.FrozenInstanceError):
        cadence.next_at = 1.0  # type: ignore[misc]


def test_a_rate_of_zero_turns_the_action_off() -> None:
    cadence = Cadence.per_second(0)
    assert not cadence.enabled
    assert runs(cadence, (100.0,))[0] == [False]


def test_positions_only_leave_load_and_temperature_out_of_the_payload() -> None:
    body = json.loads(servos_payload(0, "job", {"arm": {"gripper": ServoSample(2048)}}))
    assert body["arms"]["arm"]["motors"]["gripper"] == {"position": 2048}


def test_a_telemetry_block_decodes_feetech_sign_magnitude_values() -> None:
    # Present_Position 2048, velocity 0, Present_Load 100 with the sign bit (10) set, voltage 120, 41 °C
    block = (2048).to_bytes(2, "little") + b"\x00\x00" + (100 | 1 << 10).to_bytes(2, "little") + bytes([120, 41])
    assert decode_block(block) == ServoSample(position=2048, load=-100, temperature=41)


def test_a_short_block_is_not_a_reading() -> None:
    with pytest.raises(ValueError, match="8 bytes"):
        decode_block(b"\x00\x08")


def test_the_monitor_payload_says_complete_its_score_and_when_its_frame_was_scored() -> None:
    assert monitor_subject("cell-1") == "telemetry.cell-1.monitor"
    assert json.loads(monitor_payload(10.12345, True, 0.876543, 9.5)) == {
        "t": 10.123, "complete": True, "score": 0.8765, "frameAt": 9.5}
    assert json.loads(monitor_payload(1.0, False, 0.0, None))["frameAt"] is None

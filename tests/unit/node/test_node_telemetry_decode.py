"""What the page shows of a job's servos comes only from the job's own reads; idle reads only Feetech arms."""

from __future__ import annotations

import argparse

import pytest
from armnet_connector.config import MotorRange
from armnet_connector.identity import CellMotor
from armnet_connector.telemetry_decode import ServoSample, feetech_protocol, known_positions
from armnet_node import cli
from armnet_node.telemetry import MAX_FRAME_FPS, MAX_SERVO_HZ, TelemetrySettings
from armnet_node.telemetry_sources import CAMERA_BACKOFF

pytestmark = pytest.mark.unit

MOTORS = {"shoulder_pan": CellMotor(1, "sts3215", "degrees"), "gripper": CellMotor(6, "sts3215", "range_0_100")}
RANGES = {"shoulder_pan": MotorRange(1, 1000, 3000), "gripper": MotorRange(6, 2000, 3000)}


def test_a_job_that_read_no_position_yet_shows_none() -> None:
    assert known_positions({}, MOTORS, RANGES) is None


def test_a_raw_read_of_the_job_is_shown_as_it_is_with_no_load_or_temperature() -> None:
    present = {False: (1.0, {"shoulder_pan": 2100.0, "gripper": 2500.0})}
    assert known_positions(present, MOTORS, RANGES) == {
        "shoulder_pan": ServoSample(2100), "gripper": ServoSample(2500)}


def test_a_normalised_read_is_turned_back_into_ticks_with_the_cells_calibration() -> None:
    present = {True: (1.0, {"shoulder_pan": 0.0, "gripper": 50.0})}
    assert known_positions(present, MOTORS, RANGES) == {
        "shoulder_pan": ServoSample(2000), "gripper": ServoSample(2500)}


def test_the_newest_of_the_jobs_reads_wins() -> None:
    present = {False: (1.0, {"shoulder_pan": 1500.0}), True: (2.0, {"shoulder_pan": 0.0})}
    assert known_positions(present, MOTORS, RANGES)["shoulder_pan"] == ServoSample(2000)  # type: ignore[index]


def test_a_motor_the_jobs_read_left_out_is_shown_silent() -> None:
    present = {False: (1.0, {"shoulder_pan": 2100.0})}
    assert known_positions(present, MOTORS, RANGES)["gripper"] is None  # type: ignore[index]


@pytest.mark.parametrize(("model", "protocol"), [("sts3215", 0), ("sms_series", 0), ("xl330-m077", None),
                                                 (None, None)])
def test_only_feetech_motor_models_have_a_protocol_the_agent_reads(model: str | None, protocol: int | None) -> None:
    assert feetech_protocol(model) == protocol


def test_a_failing_camera_is_retried_ever_later_up_to_a_minute() -> None:
    assert [CAMERA_BACKOFF.delay(n) for n in (1, 2, 3, 4)] == [1.0, 2.0, 4.0, 8.0]
    assert CAMERA_BACKOFF.delay(50) == CAMERA_BACKOFF.max_s == 60.0


@pytest.mark.parametrize(("servo_hz", "frame_fps"), [(MAX_SERVO_HZ + 1, 2), (4, MAX_FRAME_FPS + 1), (-1, 2)])
def test_telemetry_rates_beyond_their_bounds_are_refused(servo_hz: float, frame_fps: float) -> None:
    with pytest.raises(ValueError, match="outside"):
        TelemetrySettings(servo_hz, frame_fps)


@pytest.mark.parametrize("flag", ["--telemetry-servo-hz=50", "--telemetry-frame-fps=30"])
def test_the_agent_cli_refuses_a_telemetry_rate_above_its_bound(flag: str, capsys: pytest.CaptureFixture[str]) -> None:
    parser = argparse.ArgumentParser()
    cli.add_arguments(parser)
    with pytest.raises(SystemExit) as exit_info:
        parser.parse_args([flag])
    assert exit_info.value.code == 2
    assert "outside 0.." in capsys.readouterr().err

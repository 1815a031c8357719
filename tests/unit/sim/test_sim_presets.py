"""Presets and calibration files: so101, bimanual_so101, cell-supplied calibrations."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from armnet_sim import (
    SO101_MOTORS,
    CalibrationError,
    SimulatedCellProcess,
    build_cell,
    builtin_calibration,
    load_calibration,
    write_calibration,
)

from .sim_lerobot_helpers import Steady, a_feetech_bus, wait_until

pytestmark = pytest.mark.unit

SO101_NAMES = ["shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll", "gripper"]


def test_so101_has_the_six_named_motors_with_ids_1_to_6() -> None:
    assert [(m.name, m.id) for m in SO101_MOTORS] == list(
        zip(SO101_NAMES, range(1, 7), strict=True)
    )
    assert {m.name: m.norm_mode for m in SO101_MOTORS}["gripper"] == "range_0_100"


def test_shipped_calibrations_are_valid_lerobot_files() -> None:
    for name in ("so101", "so101_left", "so101_right"):
        calibration = builtin_calibration(name)
        assert list(calibration) == SO101_NAMES
        assert [c.id for c in calibration.values()] == list(range(1, 7))


def test_a_calibration_file_round_trips(tmp_path: Path) -> None:
    path = write_calibration(tmp_path / "cal" / "arm.json", builtin_calibration("so101"))
    assert load_calibration(path) == builtin_calibration("so101")
    assert json.loads(path.read_text())["gripper"]["range_min"] == 2020


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("{", "not JSON"),
        ("[]", "JSON object"),
        ('{"m": {"id": 1, "drive_mode": 0, "homing_offset": 0, "range_min": 10}}', "range_max"),
        (
            '{"m": {"id": 1, "drive_mode": 0, "homing_offset": 3000, "range_min": 0, "range_max": 9}}',
            "homing_offset",
        ),
        (
            '{"m": {"id": 1, "drive_mode": 0, "homing_offset": 0, "range_min": 9, "range_max": 9}}',
            "below",
        ),
        (
            '{"m": {"id": 1, "drive_mode": 0, "homing_offset": 0, "range_min": 0, "range_max": 9, "x": 1}}',
            "x",
        ),
    ],
)
def test_bad_calibration_files_are_rejected_with_the_reason(
    tmp_path: Path, content: str, message: str
) -> None:
    path = tmp_path / "bad.json"
    path.write_text(content)
    with pytest.raises(CalibrationError, match=message):
        load_calibration(path)


def test_a_missing_calibration_file_says_which_path() -> None:
    with pytest.raises(CalibrationError, match="/nonexistent/cal.json"):
        load_calibration("/nonexistent/cal.json")


def test_the_cells_own_calibration_seeds_the_servos(tmp_path: Path) -> None:
    calibration = dict(builtin_calibration("so101"))
    calibration["elbow_flex"] = load_calibration(
        write_calibration(tmp_path / "c.json", builtin_calibration("so101_right"))
    )["elbow_flex"]
    with SimulatedCellProcess("so101", calibrations={"arm": calibration}) as cell:
        bus = Steady(a_feetech_bus(cell.arm))
        bus.connect()
        try:
            assert bus.is_calibrated
            assert bus.read_calibration()["elbow_flex"].homing_offset == 871
        finally:
            bus.disconnect()


def test_unknown_presets_and_arms_are_refused() -> None:
    with pytest.raises(ValueError, match="bimanual_so101"):
        build_cell("so100")
    with pytest.raises(ValueError, match="left"):
        build_cell("bimanual_so101", calibrations={"middle": builtin_calibration("so101")})


def test_bimanual_cell_has_two_independent_buses() -> None:
    with SimulatedCellProcess("bimanual_so101") as cell:
        left, right = cell.arms["left"], cell.arms["right"]
        assert left.port != right.port
        with pytest.raises(ValueError, match="left"):
            _ = cell.arm
        buses: dict[str, Steady] = {}
        for name, arm in cell.arms.items():
            buses[name] = Steady(a_feetech_bus(arm))
            buses[name].connect()
        try:
            assert buses["left"].is_calibrated and buses["right"].is_calibrated
            assert buses["left"].read_calibration() != buses["right"].read_calibration()
            right_before = right.positions()
            buses["left"].enable_torque()
            buses["left"].sync_write("Goal_Position", {"shoulder_pan": 25.0})
            assert wait_until(lambda: abs(left.normalized_positions()["shoulder_pan"] - 25.0) < 0.1)
            assert right.positions() == right_before
            assert not any(right.torque_enabled().values())
        finally:
            for bus in buses.values():
                bus.disconnect()


def test_a_cell_process_forwards_faults_and_errors_to_the_child() -> None:
    with SimulatedCellProcess("so101") as cell:
        cell.arm.unplug("gripper")
        with pytest.raises(KeyError, match="unknown motor"):
            cell.arm.unplug("tail")
        with pytest.raises(AttributeError):
            cell.arm.bus  # noqa: B018 - only the listed methods cross the pipe
        bus = a_feetech_bus(cell.arm)
        with pytest.raises(RuntimeError, match="Missing motor IDs"):
            bus.connect()
        bus.port_handler.closePort()


def test_a_cell_process_refuses_unknown_presets() -> None:
    with pytest.raises(ValueError, match="so101"):
        SimulatedCellProcess("so100")


def test_a_cell_process_in_a_spawned_interpreter_serves_its_port() -> None:
    with SimulatedCellProcess("so101", start_method="spawn") as cell:
        bus = Steady(a_feetech_bus(cell.arm))
        bus.connect()
        try:
            assert bus.is_calibrated
        finally:
            bus.disconnect()

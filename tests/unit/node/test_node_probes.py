"""The agent's health probe on the simulated SO-101: servos pinged, calibration registers read, pure facts out."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from armnet_node.probes import probe_arm
from armnet_sim import SimulatedCellProcess
from armnet_sim.calibration import builtin_calibration, write_calibration

pytestmark = pytest.mark.unit


@pytest.fixture
def sim_cell():
    cell = SimulatedCellProcess("so101").start()
    yield cell
    cell.stop()


def calibration_of(sim_cell: SimulatedCellProcess, tmp_path: Path) -> Path:
    path = tmp_path / "arm.json"
    write_calibration(path, builtin_calibration("so101"))
    return path


def test_a_simulated_arm_as_its_calibration_file_says_has_no_mismatch(sim_cell, tmp_path) -> None:
    probe = probe_arm(sim_cell.arm.port, calibration_of(sim_cell, tmp_path))
    assert all(model == 777 for _, model in probe.answers.values())
    assert probe.calibration_mismatches == ()


def test_servos_answering_late_within_lerobots_window_are_not_silent(sim_cell, tmp_path) -> None:
    """40 ms: past scservo_sdk's own ping window (~34 ms), within LeRobot's (50 ms). A loaded
    host answers this late; the probe must read the servos as LeRobot would, not as silent."""
    sim_cell.arm.set_latency_ms(40)
    probe = probe_arm(sim_cell.arm.port, calibration_of(sim_cell, tmp_path))
    assert all(model == 777 for _, model in probe.answers.values()), probe.answers


def test_a_servo_that_loses_several_replies_in_a_row_still_answers_the_probe(sim_cell, tmp_path) -> None:
    sim_cell.arm.drop_replies("elbow_flex", 4)
    probe = probe_arm(sim_cell.arm.port, calibration_of(sim_cell, tmp_path))
    assert probe.answers["elbow_flex"] == (3, 777)
    assert probe.calibration_mismatches == ()


def test_a_servo_whose_homing_offset_was_changed_outside_armnet_is_named(sim_cell, tmp_path) -> None:
    path = calibration_of(sim_cell, tmp_path)
    data = json.loads(path.read_text())
    data["wrist_roll"]["homing_offset"] += 37  # the file now disagrees with the servo's EEPROM
    path.write_text(json.dumps(data))
    probe = probe_arm(sim_cell.arm.port, path)
    assert len(probe.calibration_mismatches) == 1
    assert probe.calibration_mismatches[0].startswith("wrist_roll Homing_Offset holds ")


def test_a_port_that_vanished_before_the_probe_reports_every_servo_silent(tmp_path) -> None:
    probe = probe_arm(str(tmp_path / "unplugged"), None)
    assert probe.answers and all(model is None for _id, model in probe.answers.values())

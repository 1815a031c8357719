"""A named simulated cell keeps its servos' saved EEPROM across simulator restarts.

So the damage a calibration write does to a real cell (LeRobot writes Lock=0, then
homing and limits) can be reproduced, and its absence shown, by tests at all.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from armnet_sim import SimulatedCellProcess

from .sim_lerobot_helpers import a_feetech_bus

pytestmark = pytest.mark.unit


def write_homing(cell: SimulatedCellProcess, value: int, *, unlock: bool) -> None:
    bus = a_feetech_bus(cell.arm)
    bus.connect()
    if unlock:
        bus.write("Lock", "shoulder_pan", 0)
    bus.write("Homing_Offset", "shoulder_pan", value)
    bus.disconnect(disable_torque=False)


def test_an_eeprom_write_saved_with_lock_0_survives_a_restart_of_the_named_cell(tmp_path: Path) -> None:
    with SimulatedCellProcess("so101", state_dir=tmp_path) as cell:
        write_homing(cell, 500, unlock=True)
    assert (tmp_path / "so101-arm.eeprom.json").exists()
    with SimulatedCellProcess("so101", state_dir=tmp_path) as cell:
        assert cell.arm.register("shoulder_pan", "Homing_Offset") == 500


def test_an_eeprom_write_under_lock_is_gone_after_a_restart(tmp_path: Path) -> None:
    with SimulatedCellProcess("so101", state_dir=tmp_path) as cell:
        seeded = cell.arm.register("shoulder_pan", "Homing_Offset")
        write_homing(cell, 500, unlock=False)
        assert cell.arm.register("shoulder_pan", "Homing_Offset") == 500
    with SimulatedCellProcess("so101", state_dir=tmp_path) as cell:
        assert cell.arm.register("shoulder_pan", "Homing_Offset") == seeded


def test_a_cell_without_a_state_dir_starts_from_its_calibration_every_time(tmp_path: Path) -> None:
    with SimulatedCellProcess("so101") as cell:
        seeded = cell.arm.register("shoulder_pan", "Homing_Offset")
        write_homing(cell, 500, unlock=True)
    with SimulatedCellProcess("so101") as cell:
        assert cell.arm.register("shoulder_pan", "Homing_Offset") == seeded

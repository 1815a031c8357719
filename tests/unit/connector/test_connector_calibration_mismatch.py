"""A servo's EEPROM calibration changed outside armnet is reported when a job's bus connects, never "fixed".

On the simulated SO-101: the servo is changed with a bare LeRobot bus on the
simulator's port (as someone with a USB cable would), then a job connects
through the connector; the connector's record names the servo and register.
"""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Callable
from typing import Any, TypeVar

import pytest
from armnet_connector.calibration_check import CALIBRATION_REGISTERS, read_calibration
from armnet_connector.retry import RETRY_DELAY_S, drop_pending_input
from armnet_runtime.lerobot.remote_feetech import RemoteFeetechMotorsBus

pytestmark = pytest.mark.unit

_T = TypeVar("_T")


def asked_until_answered(bare: Any, call: Callable[[], _T], tries: int = 5) -> _T:
    """``call`` on a bare LeRobot bus, asked again after a lost reply once the late one is dropped.

    LeRobot's own ``num_retry`` asks again at once: a late reply then answers the next request
    (a status packet names the servo, not the register), and a loaded host made this test's
    reference values shift by one register.
    """
    for attempt in range(tries):
        try:
            return call()
        except ConnectionError:
            if attempt == tries - 1:
                raise
            time.sleep(RETRY_DELAY_S)  # past the reply window, as the connector's own retries wait
            drop_pending_input(bare)
    raise AssertionError("unreachable")


def change_homing_outside_armnet(port: str, motors: dict[str, Any], motor: str, value: int) -> None:
    from lerobot.motors.feetech import FeetechMotorsBus

    bare = FeetechMotorsBus(port=port, motors=motors)
    bare.connect(handshake=False)
    for register, written in (("Lock", 0), ("Homing_Offset", value), ("Lock", 1)):  # absolute values
        asked_until_answered(bare, lambda r=register, v=written: bare.write(r, motor, v, normalize=False))
    bare.disconnect(disable_torque=False)


def test_a_cell_as_its_file_says_reports_no_calibration_mismatch(sim_cell, make_connector, cell_config, motors) -> None:
    connector = make_connector(cell_config(sim_cell))
    job = RemoteFeetechMotorsBus(port=connector.robot_endpoint, motors=motors)
    job.connect()
    job.disconnect()
    record = connector.record()
    assert record.calibration_ok and record.as_dict()["calibrationMismatches"] == {}


def test_a_homing_offset_changed_outside_armnet_is_reported_at_connect_and_left_alone(
    sim_cell, make_connector, cell_config, motors
) -> None:
    cell_homing = sim_cell.arm.register("wrist_roll", "Homing_Offset")
    change_homing_outside_armnet(sim_cell.arm.port, motors, "wrist_roll", cell_homing + 37)
    connector = make_connector(cell_config(sim_cell))
    job = RemoteFeetechMotorsBus(port=connector.robot_endpoint, motors=motors)
    job.connect()
    job.disconnect()
    record = connector.record()
    assert not record.calibration_ok
    (note,) = record.calibration_mismatches["arm"]
    assert "servo 5" in note and f"Homing_Offset is {cell_homing + 37}" in note
    assert sim_cell.arm.register("wrist_roll", "Homing_Offset") == cell_homing + 37  # reported, not "fixed"


def test_read_calibration_reads_every_servo_of_the_cell_on_the_port(sim_cell, motors) -> None:
    held = read_calibration(sim_cell.arm.port, [motor.id for motor in motors.values()])
    assert sorted(held) == [1, 2, 3, 4, 5, 6]
    assert held[5] is not None and held[5][0] == sim_cell.arm.register("wrist_roll", "Homing_Offset")


def test_read_calibration_gives_the_values_lerobot_reads_including_a_negative_homing_offset(
    sim_cell, motors
) -> None:
    from lerobot.motors.feetech import FeetechMotorsBus

    change_homing_outside_armnet(sim_cell.arm.port, motors, "elbow_flex", -321)  # sign-magnitude on the wire
    bare = FeetechMotorsBus(port=sim_cell.arm.port, motors=motors)
    bare.connect(handshake=False)
    try:
        lerobot = {
            motor.id: tuple(int(asked_until_answered(bare, lambda r=register, n=name: bare.read(r, n, normalize=False)))
                            for register in ("Homing_Offset", "Min_Position_Limit", "Max_Position_Limit"))
            for name, motor in motors.items()
        }
    finally:
        bare.disconnect(disable_torque=False)
    held = read_calibration(sim_cell.arm.port, lerobot)
    assert held == lerobot
    assert held[motors["elbow_flex"].id] == (-321, *lerobot[motors["elbow_flex"].id][1:])


def test_replies_after_the_window_never_read_as_another_registers_value(sim_cell, motors) -> None:
    """Every reply 60 ms late (the window is 50 ms): a late reply must not answer the next request."""
    truth = {motor.id: tuple(sim_cell.arm.register(name, r) for r in CALIBRATION_REGISTERS)
             for name, motor in motors.items() if name in ("shoulder_pan", "shoulder_lift")}
    sim_cell.arm.set_latency_ms(60)
    try:
        held = read_calibration(sim_cell.arm.port, truth)
    finally:
        sim_cell.arm.set_latency_ms(0)
    # Unanswered (None), or answered by its own reply when one squeezed into the window: never
    # a value shifted from another register (the SDK's immediate retry read (112, 112, ...) here).
    assert sorted(held) == sorted(truth)
    assert all(held[motor_id] in (None, truth[motor_id]) for motor_id in truth), (held, truth)


def test_read_calibration_reports_a_servo_that_does_not_answer_as_none(sim_cell) -> None:
    assert read_calibration(sim_cell.arm.port, [1, 42]) == {1: read_calibration(sim_cell.arm.port, [1])[1], 42: None}


def test_read_calibration_never_loads_lerobot() -> None:
    code = (
        "import sys\n"
        "from armnet_connector.calibration_check import read_calibration\n"
        "try:\n"
        "    read_calibration('/dev/null-armnet-no-such-port', [1])\n"
        "except ConnectionError:\n"
        "    pass\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] == 'lerobot'))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"

"""The register write policy, the cell-owned calibration and the clamp|trip safety policy.

Every test goes through the real LeRobot bus behind the connector, on the
simulated SO-101, and checks the servos' registers on the simulator's side.
"""

from __future__ import annotations

import math

import pytest
from armnet_runtime.errors import RemoteCallError, SafetyViolation
from armnet_runtime.lerobot.remote_feetech import RemoteFeetechMotorsBus

pytestmark = pytest.mark.unit

#: (register, value) writes a job could make to unsettle a cell: without the policy, the bus takes them all.
HOSTILE_WRITES = [
    ("Operating_Mode", 1),
    ("Min_Position_Limit", 0),
    ("Max_Position_Limit", 4095),
    ("Homing_Offset", 500),
    ("Torque_Limit", 0),
    ("Goal_Velocity", 3000),
    ("Lock", 0),
    ("Return_Delay_Time", 250),
    ("Baud_Rate", 4),
    ("P_Coefficient", 8),  # EEPROM: the cell's gains
    ("Max_Torque_Limit", 200),  # EEPROM: loaded into Torque_Limit at every power-on
]


@pytest.fixture
def connector(sim_cell, make_connector, cell_config):
    return make_connector(cell_config(sim_cell))


@pytest.fixture
def bus(connector, motors, calibration):
    remote = RemoteFeetechMotorsBus(port=connector.robot_endpoint, motors=motors, calibration=calibration)
    remote.connect()
    yield remote
    if remote.is_connected:
        remote.disconnect()


def refused(call, *args, **kwargs) -> RemoteCallError:
    with pytest.raises(RemoteCallError) as raised:
        call(*args, **kwargs)
    assert raised.value.error_type == "NotAllowed", raised.value
    return raised.value


# -- register policy (docs/connector.md, "Register write policy") -------------------------


@pytest.mark.parametrize(("register", "value"), HOSTILE_WRITES)
def test_a_write_outside_the_register_policy_is_refused_naming_the_register(bus, sim_cell, register, value) -> None:
    before = sim_cell.arm.register("wrist_flex", register)
    error = refused(bus.write, register, "wrist_flex", value, normalize=False)
    assert register in str(error)
    assert sim_cell.arm.register("wrist_flex", register) == before


def test_a_sync_write_outside_the_policy_is_refused_and_changes_no_servo(bus, sim_cell) -> None:
    before = {m: sim_cell.arm.register(m, "Torque_Limit") for m in sim_cell.arm.motors}
    refused(bus.sync_write, "Torque_Limit", 0, normalize=False)
    assert {m: sim_cell.arm.register(m, "Torque_Limit") for m in sim_cell.arm.motors} == before


def test_values_inside_the_cells_bounds_are_written(bus, sim_cell) -> None:
    bus.write("Acceleration", "elbow_flex", 100)
    bus.write("Torque_Limit", "elbow_flex", 400)
    assert sim_cell.arm.register("elbow_flex", "Acceleration") == 100
    assert sim_cell.arm.register("elbow_flex", "Torque_Limit") == 400


def test_lerobots_configure_sequence_succeeds_on_the_cell(bus, sim_cell) -> None:
    """What SO101Follower.configure() writes (lerobot 0.4.4), through the job's bus."""
    from lerobot.motors.feetech import OperatingMode

    with bus.torque_disabled():
        bus.configure_motors()
        for motor in bus.motors:
            bus.write("Operating_Mode", motor, OperatingMode.POSITION.value)
            bus.write("P_Coefficient", motor, 16)
            bus.write("I_Coefficient", motor, 0)
            bus.write("D_Coefficient", motor, 32)
            if motor == "gripper":
                bus.write("Max_Torque_Limit", motor, 500)
                bus.write("Protection_Current", motor, 250)
                bus.write("Overload_Torque", motor, 25)
    assert sim_cell.arm.register("gripper", "Max_Torque_Limit") == 500
    assert sim_cell.arm.register("gripper", "Lock") == 1  # the EEPROM stayed locked throughout
    assert bus.is_calibrated



def test_a_late_write_acknowledgement_is_not_taken_for_the_value_an_eeprom_write_would_replace(bus, sim_cell) -> None:
    """A loaded host refused LeRobot's configure(): "Maximum_Acceleration ... the servo holds 251".

    The write before it was acknowledged late, and the one-byte read of the held value
    took that empty acknowledgement's checksum byte as its answer.
    """
    held = sim_cell.arm.register("wrist_flex", "Maximum_Acceleration")
    sim_cell.arm.send_stale_acks("wrist_flex", 1)
    bus.write("Maximum_Acceleration", "wrist_flex", held, normalize=False)
    assert sim_cell.arm.register("wrist_flex", "Maximum_Acceleration") == held
    assert bus.read("Maximum_Acceleration", "wrist_flex", normalize=False) == held  # the line was left clean


SO101_JOB = """
import sys
from pathlib import Path
from armnet_runtime.lerobot.import_swap import install_lerobot_remote_mode
install_lerobot_remote_mode()
from lerobot.robots.so_follower import SO101Follower, SO101FollowerConfig
config = SO101FollowerConfig(port=sys.argv[1], id="sim-so101", calibration_dir=Path(sys.argv[2]), use_degrees=True)
robot = SO101Follower(config)
robot.connect()
assert robot.is_calibrated
robot.send_action({k: v for k, v in robot.get_observation().items() if k.endswith(".pos")})
robot.disconnect()
print("ok")
"""


def test_the_real_so101_follower_connects_and_configures(connector, tmp_path, calibration_path) -> None:
    """Unmodified LeRobot robot code, in a job process of its own (the import swap is process-wide)."""
    import os
    import shutil
    import subprocess
    import sys

    import lerobot.robots.so_follower  # noqa: F401 — scripts/setup.sh installs what LeRobot's robot classes need
    shutil.copy(calibration_path("so101"), tmp_path / "sim-so101.json")
    job = subprocess.run(
        [sys.executable, "-c", SO101_JOB, connector.robot_endpoint, str(tmp_path)],
        capture_output=True, text=True, timeout=120, env=dict(os.environ),
    )
    assert job.returncode == 0 and job.stdout.strip().endswith("ok"), job.stderr[-3000:]


def test_under_the_interlock_only_torque_off_is_written(bus, sim_cell, connector) -> None:
    from armnet_connector.interlock import TripReason

    bus.enable_torque()
    connector.interlock.trip(TripReason.SAFETY, "tripped by the test")
    with pytest.raises(RemoteCallError):
        bus.write("Lock", "gripper", 0)
    with pytest.raises(RemoteCallError):
        bus.enable_torque()
    bus.disable_torque()
    assert not any(sim_cell.arm.torque_enabled().values())
    assert sim_cell.arm.register("gripper", "Lock") == 1


def test_the_calibration_attribute_is_read_only(bus, calibration) -> None:
    refused(setattr, bus, "calibration", {})
    assert bus.calibration == calibration


# -- calibration belongs to the cell (docs/connector.md) ----------------------------------


@pytest.mark.parametrize(
    ("method", "args"),
    [
        ("set_half_turn_homings", ()),
        ("record_ranges_of_motion", ()),
        ("reset_calibration", ()),
        ("write_calibration", ("CELL",)),
    ],
)
def test_calibration_methods_are_refused_pointing_at_the_cells_calibration(
    bus, sim_cell, calibration, method, args
) -> None:
    before = {m: sim_cell.arm.register(m, "Homing_Offset") for m in sim_cell.arm.motors}
    call_args = tuple(calibration if a == "CELL" else a for a in args)
    error = refused(getattr(bus, method), *call_args)
    assert "ctx.cell.calibration_dir" in str(error)
    assert {m: sim_cell.arm.register(m, "Homing_Offset") for m in sim_cell.arm.motors} == before


def test_a_refused_calibration_leaves_the_next_job_calibrated(connector, motors, sim_cell) -> None:
    first = RemoteFeetechMotorsBus(port=connector.robot_endpoint, motors=motors)
    first.connect()
    with pytest.raises(RemoteCallError):
        first.set_half_turn_homings()
    with pytest.raises(RemoteCallError):
        first.write("Homing_Offset", "shoulder_pan", 500, normalize=False)
    first.disconnect()
    second = RemoteFeetechMotorsBus(port=connector.robot_endpoint, motors=motors)
    second.connect()
    assert second.is_calibrated
    second.disconnect()


def test_a_refused_calibration_leaves_the_cell_calibrated_after_a_simulator_restart(
    tmp_path, make_connector, cell_config, motors
) -> None:
    """A job unlocks EEPROM and rewrites homing and limits: refused, on a named cell whose EEPROM survives restarts."""
    from armnet_sim import SimulatedCellProcess

    with SimulatedCellProcess("so101", state_dir=tmp_path) as sim:
        connector = make_connector(cell_config(sim))
        job = RemoteFeetechMotorsBus(port=connector.robot_endpoint, motors=motors)
        job.connect()
        for attempt in (job.set_half_turn_homings, lambda: job.write("Lock", "gripper", 0),
                        lambda: job.write("Homing_Offset", "gripper", 300)):
            with pytest.raises(RemoteCallError):
                attempt()
        job.disconnect()
        connector.stop()
    with SimulatedCellProcess("so101", state_dir=tmp_path) as sim:
        connector = make_connector(cell_config(sim))
        next_job = RemoteFeetechMotorsBus(port=connector.robot_endpoint, motors=motors)
        next_job.connect()
        assert next_job.is_calibrated
        next_job.disconnect()


# -- safety semantics (docs/connector.md, "Safety") --------------------------------------


def test_clamp_is_the_default_a_far_goal_moves_by_the_limit_and_is_counted(bus, sim_cell, connector) -> None:
    bus.enable_torque()
    present = bus.sync_read("Present_Position")
    bus.sync_write("Goal_Position", {"elbow_flex": present["elbow_flex"] + 45.0})
    assert not connector.interlock.tripped
    assert bus.read("Goal_Position", "elbow_flex") == pytest.approx(present["elbow_flex"] + 30.0, abs=0.2)
    report = connector.safety_report()
    assert report.policy == "clamp" and report.clamps == {"elbow_flex": 1}
    assert report.largest_requested_step["elbow_flex"] == pytest.approx(45.0, abs=0.5)


def test_a_single_raw_write_beyond_the_limit_is_clamped_too(bus, sim_cell, connector) -> None:
    bus.enable_torque()
    before = sim_cell.arm.positions()["wrist_flex"]
    bus.write("Goal_Position", "wrist_flex", before - 1000, normalize=False)
    assert before - sim_cell.arm.goal_positions()["wrist_flex"] == math.floor(30.0 * 4095 / 360)
    assert connector.safety_report().clamps == {"wrist_flex": 1}


def test_the_report_counts_the_calls_carried_to_the_cell_and_not_the_refused_ones(bus, sim_cell, connector) -> None:
    """``deviceCalls``: what says a job reached the cell (a pre-flight that only ran out its seconds did not)."""
    before = connector.safety_report().device_calls
    assert before > 0  # the fixture's bus connected through the connector
    bus.sync_read("Present_Position")
    bus.read("Present_Position", "elbow_flex")
    assert connector.safety_report().device_calls == before + 2
    with pytest.raises(ValueError):
        bus.sync_write("Goal_Position", {"elbow_flex": float("nan")})  # refused at the safety check
    assert connector.safety_report().as_status()["deviceCalls"] == before + 2


def test_the_records_counters_carry_the_safety_reports_totals_for_the_agents_metrics(bus, sim_cell, connector) -> None:
    bus.enable_torque()
    before = sim_cell.arm.positions()["wrist_flex"]
    bus.write("Goal_Position", "wrist_flex", before - 1000, normalize=False)  # clamped
    with pytest.raises(ValueError):
        bus.sync_write("Goal_Position", {"elbow_flex": float("nan")})  # refused, trips
    counters = connector.record().counters
    assert (counters["safety_clamps"], counters["safety_refusals"], counters["safety_trips"]) == (1, 1, 1)


@pytest.mark.parametrize(("goal", "kind"), [(float("nan"), "non_finite"), (float("inf"), "non_finite"), ("far", "wrong_type")])
def test_a_goal_that_is_not_a_finite_number_is_refused_as_value_error_and_trips_the_interlock(
    bus, connector, goal, kind
) -> None:
    bus.enable_torque()
    with pytest.raises(ValueError):  # as LeRobot: a bad value is a ValueError, whatever its type
        bus.sync_write("Goal_Position", {"elbow_flex": goal})
    assert connector.interlock.tripped
    report = connector.safety_report()
    assert [r.kind for r in report.refusals] == [kind] and report.interlock_trips == 1


def test_a_goal_outside_the_calibrated_range_is_refused_even_under_clamp(bus, sim_cell, connector) -> None:
    bus.enable_torque()
    before = sim_cell.arm.goal_positions()
    with pytest.raises(SafetyViolation) as raised:
        bus.write("Goal_Position", "wrist_flex", 10, normalize=False)
    assert raised.value.error_type == "SafetyViolation"
    assert sim_cell.arm.goal_positions() == before
    assert connector.interlock.tripped
    assert connector.safety_report().refusals[0].kind == "out_of_range"


def test_torque_off_is_confirmed_in_the_report_when_the_connector_lets_go(connector, motors, sim_cell) -> None:
    bus = RemoteFeetechMotorsBus(port=connector.robot_endpoint, motors=motors)
    bus.connect()
    bus.enable_torque()
    connector.stop()
    assert not any(sim_cell.arm.torque_enabled().values())
    assert connector.safety_report().torque_off_confirmed == {"arm": True}
    assert connector.safety_report().as_status()["torqueOffConfirmed"] == {"arm": True}


# -- calibration jobs (allowCalibrationJobs) ------------------------------------------------


def test_a_calibration_job_may_rewrite_eeprom_and_the_connector_restores_the_cells(
    sim_cell, make_connector, cell_config, motors
) -> None:
    connector = make_connector(cell_config(sim_cell, allowCalibrationJobs=True))
    seeded = sim_cell.arm.register("gripper", "Homing_Offset")
    job = RemoteFeetechMotorsBus(port=connector.robot_endpoint, motors=motors)
    job.connect()
    job.write("Lock", "gripper", 0, normalize=False)
    job.write("Homing_Offset", "gripper", seeded + 100, normalize=False)
    assert sim_cell.arm.register("gripper", "Homing_Offset") == seeded + 100
    job.disconnect()
    assert sim_cell.arm.register("gripper", "Homing_Offset") == seeded
    assert sim_cell.arm.register("gripper", "Lock") == 1
    assert connector.safety_report().calibration["arm"][-1] == "end: the cell's calibration is in place"


@pytest.mark.parametrize(
    ("field", "value"),
    [("id", [1, 1]), ("range_min", 870.5), ("range_max", True), ("homing_offset", "0"), ("drive_mode", 7)],
)
def test_a_calibration_job_may_not_write_a_calibration_of_odd_values(
    sim_cell, make_connector, cell_config, motors, calibration, field, value
) -> None:
    """LeRobot keeps write_calibration's dict as the bus's calibration unchecked, and every later
    goal is converted with it: a value that is not a whole number is refused before the bus."""
    import dataclasses

    import numpy as np

    connector = make_connector(cell_config(sim_cell, allowCalibrationJobs=True))
    job = RemoteFeetechMotorsBus(port=connector.robot_endpoint, motors=motors, calibration=calibration)
    job.connect()
    odd = dict(calibration)
    odd["shoulder_pan"] = dataclasses.replace(
        calibration["shoulder_pan"], **{field: np.array(value) if isinstance(value, list) else value}
    )
    with pytest.raises(TypeError, match=rf"shoulder_pan\.{field} must be (an int|0 or 1), .*; nothing was written"):
        job.write_calibration(odd)
    assert job.read_calibration() == calibration  # the servos' EEPROM kept the cell's calibration
    job.write_calibration(dict(calibration))  # whole numbers are written as before
    job.disconnect()


@pytest.mark.parametrize(
    ("field", "value", "error"),
    [("range_min", 2**63, "exceeds the maximum"), ("range_max", -5, "Negative values"),
     ("homing_offset", 10**9, "exceeds 2047")],
)
def test_a_calibration_beyond_what_its_registers_hold_is_refused_and_not_kept(
    sim_cell, make_connector, cell_config, motors, calibration, field, value, error
) -> None:
    """Whole numbers past a register's range: LeRobot's own encoding refuses them before it
    keeps the dict, so neither the servos nor the guard's conversion see them."""
    import dataclasses

    connector = make_connector(cell_config(sim_cell, allowCalibrationJobs=True))
    job = RemoteFeetechMotorsBus(port=connector.robot_endpoint, motors=motors, calibration=calibration)
    job.connect()
    odd = dict(calibration)
    odd["shoulder_pan"] = dataclasses.replace(calibration["shoulder_pan"], **{field: value})
    with pytest.raises(ValueError, match=error):
        job.write_calibration(odd)
    assert job.read_calibration() == calibration
    assert job.calibration == calibration  # the bus kept the cell's calibration, not the job's
    job.disconnect()


def test_a_calibration_job_still_may_not_re_address_a_servo(sim_cell, make_connector, cell_config, motors) -> None:
    connector = make_connector(cell_config(sim_cell, allowCalibrationJobs=True))
    job = RemoteFeetechMotorsBus(port=connector.robot_endpoint, motors=motors)
    job.connect()
    refused(job.write, "ID", "gripper", 9)
    job.disconnect()


def _record_ranges(sim_cell, make_connector, cell_config, motors, *, lose_replies_at_poll: int | None = None):
    """A calibration job records its ranges while the operator moves each joint by 150 ticks and confirms.

    Returns the arm's start positions, the recorded (mins, maxes) and the connector.
    ``lose_replies_at_poll``: at that poll the simulated wrist loses its next reply.
    """
    from armnet_connector import LocalOperatorInputs

    start = sim_cell.arm.positions()
    polls: list[int] = []

    def operator(inputs: LocalOperatorInputs) -> None:  # called at each poll of the recording
        polls.append(1)
        if len(polls) == lose_replies_at_poll:
            sim_cell.arm.drop_replies("wrist_flex", 1)
        if len(polls) == 2:
            for motor, position in start.items():
                sim_cell.arm.move_by_hand(motor, position + 150)
        if len(polls) == 4:
            inputs.confirm_reset()

    connector = make_connector(
        cell_config(sim_cell, allowCalibrationJobs=True), inputs=LocalOperatorInputs(on_reset_requested=operator)
    )
    job = RemoteFeetechMotorsBus(port=connector.robot_endpoint, motors=motors)
    job.connect()
    job.disable_torque()
    ranges = job.record_ranges_of_motion()
    job.disconnect()
    return start, ranges, connector


def test_a_calibration_jobs_range_recording_ends_on_the_operators_confirmation_not_the_connectors_stdin(
    sim_cell, make_connector, cell_config, motors, capsys
) -> None:
    """pytest's stdin cannot be read: LeRobot's own loop (Enter on stdin) would fail here."""
    start, (mins, maxes), _connector = _record_ranges(sim_cell, make_connector, cell_config, motors)
    assert {m: (mins[m], maxes[m]) for m in start} == {m: (p, p + 150) for m, p in start.items()}
    assert "NAME" not in capsys.readouterr().out  # no live table on the connector's terminal


def test_a_range_recording_poll_that_lost_a_servo_reply_asks_again_and_the_recording_completes(
    sim_cell, make_connector, cell_config, motors
) -> None:
    """A loaded CI host lost one reply in a recording's polls and the whole calibration failed with it."""
    start, (mins, maxes), connector = _record_ranges(
        sim_cell, make_connector, cell_config, motors, lose_replies_at_poll=3
    )
    assert {m: (mins[m], maxes[m]) for m in start} == {m: (p, p + 150) for m, p in start.items()}
    assert connector.counters.bus_retries >= 1

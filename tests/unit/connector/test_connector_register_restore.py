"""The cell as the job found it: registers a job tuned go back when its bus lets go; EEPROM stays the cell's.

Every test drives the real LeRobot bus behind the connector on the simulated SO-101
(a pty, the real scservo_sdk) and reads the servos' registers on the simulator's side.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable

import pytest
from armnet_runtime.errors import RemoteCallError
from armnet_runtime.lerobot.remote_feetech import RemoteFeetechMotorsBus

pytestmark = pytest.mark.unit

#: (motor, register, value inside the default bounds, unlike what the simulated cell holds).
TUNED = [("elbow_flex", "Torque_Limit", 300), ("gripper", "Torque_Limit", 250),
         ("elbow_flex", "Acceleration", 10), ("wrist_flex", "Goal_Velocity", 100)]
#: Generous: a loaded 2-core host can take seconds to notice a dead connection and release.
RELEASE_WAIT_S = 30.0


def wait_until(predicate: Callable[[], bool], timeout: float = RELEASE_WAIT_S) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.05)
    return predicate()


def held(sim_cell) -> dict[tuple[str, str], int]:
    return {(motor, register): sim_cell.arm.register(motor, register) for motor, register, _ in TUNED}


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


def tuned_by_a_raw_client(connector, client_for, motors):
    """A job's connection on the wire (no SDK), its bus connected and every TUNED register written."""
    client = client_for(connector.robot_endpoint)
    bus = client.create("FeetechMotorsBus", port=connector.robot_endpoint, motors=motors)
    assert client.call(bus, "connect")["ok"]
    for motor, register, value in TUNED:
        assert client.call(bus, "write", register, motor, value)["ok"]
    return client


def tune(bus) -> None:
    """The job's writes: single writes and a sync_write, all inside the cell's bounds."""
    bus.write("Torque_Limit", "elbow_flex", 300)
    bus.sync_write("Torque_Limit", {"gripper": 250})
    bus.sync_write("Acceleration", {"elbow_flex": 10})
    bus.write("Goal_Velocity", "wrist_flex", 100)


def assert_tuned(sim_cell) -> None:
    assert held(sim_cell) == {(m, r): v for m, r, v in TUNED}  # the writes reached the servos


def test_what_a_job_tuned_is_back_as_it_found_it_after_its_disconnect(bus, sim_cell, connector) -> None:
    found = held(sim_cell)
    tune(bus)
    assert_tuned(sim_cell)
    bus.disconnect()
    assert held(sim_cell) == found
    restored = connector.safety_report().registers_restored["arm"]
    assert restored["elbow_flex"]["Torque_Limit"] == (300, found[("elbow_flex", "Torque_Limit")])
    assert restored["gripper"]["Torque_Limit"] == (250, found[("gripper", "Torque_Limit")])
    assert restored["elbow_flex"]["Acceleration"] == (10, found[("elbow_flex", "Acceleration")])
    assert restored["wrist_flex"]["Goal_Velocity"] == (100, found[("wrist_flex", "Goal_Velocity")])
    status = connector.safety_report().as_status()
    assert status["registersRestored"]["arm"]["gripper"]["Torque_Limit"] == {"found": 250, "restoredTo": 500}
    assert status["registerRestoreFailures"] == {}
    assert connector.record().registers_restored and connector.counters.registers_restored == 4


def test_a_register_the_job_put_back_itself_is_not_reported(bus, sim_cell, connector) -> None:
    found = sim_cell.arm.register("shoulder_pan", "Acceleration")
    bus.write("Acceleration", "shoulder_pan", 50)
    bus.write("Acceleration", "shoulder_pan", found)
    bus.disconnect()
    assert connector.safety_report().registers_restored == {}


def test_a_dropped_connection_leaves_the_registers_as_the_job_found_them(
    connector, client_for, sim_cell, motors
) -> None:
    found = held(sim_cell)
    client = tuned_by_a_raw_client(connector, client_for, motors)
    assert_tuned(sim_cell)
    client.close()  # no disconnect, no close: the connection just ends
    assert wait_until(lambda: held(sim_cell) == found), held(sim_cell)


JOB = """
import sys
from armnet_runtime.lerobot.remote_feetech import RemoteFeetechMotorsBus
from lerobot.motors import Motor, MotorNormMode
names = ["shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll"]
motors = {n: Motor(i + 1, "sts3215", MotorNormMode.DEGREES) for i, n in enumerate(names)}
motors["gripper"] = Motor(6, "sts3215", MotorNormMode.RANGE_0_100)
bus = RemoteFeetechMotorsBus(port=sys.argv[1], motors=motors)
bus.connect()
bus.write("Torque_Limit", "elbow_flex", 300)
bus.sync_write("Torque_Limit", {"gripper": 250})
bus.sync_write("Acceleration", {"elbow_flex": 10})
bus.write("Goal_Velocity", "wrist_flex", 100)
print("tuned", flush=True)
while True:  # a control loop: the kill lands between or inside calls
    bus.sync_read("Present_Position")
    bus.write("Torque_Limit", "elbow_flex", 300)
"""


def test_a_killed_job_process_leaves_the_registers_as_it_found_them(connector, sim_cell) -> None:
    found = held(sim_cell)
    job = subprocess.Popen([sys.executable, "-c", JOB, connector.robot_endpoint], stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True, env=dict(os.environ))
    try:
        assert job.stdout is not None and job.stdout.readline().strip() == "tuned", job.stderr and job.stderr.read()
        assert_tuned(sim_cell)
        job.send_signal(signal.SIGKILL)
        job.wait(timeout=30)
    finally:
        if job.poll() is None:
            job.kill()
            job.wait()
    assert wait_until(lambda: held(sim_cell) == found), held(sim_cell)
    assert not any(sim_cell.arm.torque_enabled().values())
    assert connector.record().registers_restored


def test_the_connectors_stop_puts_back_what_a_job_still_holding_its_bus_tuned(
    connector, client_for, sim_cell, motors
) -> None:
    found = held(sim_cell)
    _still_connected = tuned_by_a_raw_client(connector, client_for, motors)
    connector.stop()  # the interlock trips first: the restore is the connector's, not the job's
    assert held(sim_cell) == found
    assert set(connector.safety_report().registers_restored["arm"]) == {"elbow_flex", "gripper", "wrist_flex"}


def test_the_restore_holds_a_powered_arm_where_it_is_instead_of_finishing_the_jobs_move(
    sim_cell, make_connector, cell_config, motors, calibration
) -> None:
    """With torque kept on, a slow move cut short stays where it is: the restored speed never completes it."""
    connector = make_connector(cell_config(sim_cell, disableTorqueOnShutdown=False))
    bus = RemoteFeetechMotorsBus(port=connector.robot_endpoint, motors=motors, calibration=calibration)
    bus.connect()
    start = sim_cell.arm.positions()["shoulder_pan"]
    bus.write("Goal_Velocity", "shoulder_pan", 5)  # 5 ticks/s: the move below would take a minute
    bus.enable_torque()
    goal = start + 300  # inside the cell's 30-degree step (341 ticks)
    bus.write("Goal_Position", "shoulder_pan", goal, normalize=False)
    bus.disconnect(disable_torque=False)
    assert sim_cell.arm.torque_enabled()["shoulder_pan"]
    assert sim_cell.arm.register("shoulder_pan", "Goal_Velocity") == 0  # restored: the servo's full speed
    held_goal = sim_cell.arm.goal_positions()["shoulder_pan"]
    assert held_goal != goal and abs(held_goal - start) < 150, (start, held_goal)


def test_a_restore_that_cannot_reach_a_servo_is_reported_and_tried_again_at_the_stop(
    bus, sim_cell, connector
) -> None:
    found = sim_cell.arm.register("wrist_roll", "Torque_Limit")
    bus.write("Torque_Limit", "wrist_roll", 400)
    bus.write("Acceleration", "elbow_flex", 10)
    sim_cell.arm.unplug("wrist_roll")
    bus.disconnect()  # LeRobot's torque off cannot reach the unplugged servo: reported, the port still closes
    failures = connector.safety_report().restore_failures["arm"]
    assert len(failures) == 1 and "wrist_roll (id 5): Torque_Limit" in failures[0] and str(found) in failures[0]
    assert not connector.record().registers_restored
    assert connector.record().as_dict()["registerRestoreFailures"] == {"arm": list(failures)}
    assert sim_cell.arm.register("elbow_flex", "Acceleration") != 10  # the servos that answer are restored
    assert connector.counters.register_restore_failures == 1
    sim_cell.arm.plug("wrist_roll")
    connector.stop()
    assert sim_cell.arm.register("wrist_roll", "Torque_Limit") == found
    assert connector.record().registers_restored


@pytest.mark.parametrize(("register", "motor", "value", "holds"), [
    ("Max_Torque_Limit", "gripper", 300, 500),
    ("Max_Torque_Limit", "elbow_flex", 200, 1000),
    ("P_Coefficient", "elbow_flex", 24, 16),
    ("Protection_Current", "gripper", 500, 250),
])
def test_a_job_cannot_change_an_eeprom_register_and_is_told_why(bus, sim_cell, register, motor, value, holds) -> None:
    assert sim_cell.arm.register(motor, register) == holds
    with pytest.raises(RemoteCallError) as raised:
        bus.write(register, motor, value, normalize=False)
    assert raised.value.error_type == "NotAllowed"
    assert "EEPROM" in str(raised.value) and f"holds {holds}" in str(raised.value)
    assert sim_cell.arm.register(motor, register) == holds


def test_a_sync_write_to_an_eeprom_register_is_refused(bus, sim_cell) -> None:
    with pytest.raises(RemoteCallError) as raised:
        bus.sync_write("Max_Torque_Limit", {"gripper": 500}, normalize=False)  # even the value it holds
    assert raised.value.error_type == "NotAllowed" and "EEPROM" in str(raised.value)

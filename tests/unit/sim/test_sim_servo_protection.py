"""The simulated STS3215's protections and line speed, through LeRobot's real FeetechMotorsBus.

Overload protection drops the torque and reports bit 5 (overload) in the status
byte, Torque_Limit caps the effort, and a servo set to another Baud_Rate is not
on the host's line any more.
"""

from __future__ import annotations

import time

import pytest
from armnet_sim import RemoteArm
from armnet_sim.physics import Drive, JointState, PhysicsParams, step, telemetry
from armnet_sim.servo import OVERLOAD_BIT

from .sim_lerobot_helpers import a_feetech_bus, wait_until

pytestmark = pytest.mark.unit


def test_a_persisting_overload_drops_torque_and_sets_the_overload_bit(so101_arm: RemoteArm) -> None:
    bus = a_feetech_bus(so101_arm)
    bus.connect()
    try:
        bus.write("Protection_Time", "shoulder_pan", 10)  # 100 ms instead of 2 s: the rule, sooner
        bus.enable_torque()
        so101_arm.block("shoulder_pan")  # an obstacle holds the joint
        start = bus.read("Present_Position", "shoulder_pan", normalize=False)
        bus.write("Goal_Position", "shoulder_pan", start + 600, normalize=False)  # load > Overload_Torque
        assert wait_until(lambda: so101_arm.register("shoulder_pan", "Torque_Enable") == 0, timeout_s=3)
        assert so101_arm.register("shoulder_pan", "Status") & OVERLOAD_BIT
        with pytest.raises(RuntimeError, match="Overload"):  # LeRobot raises on a status with ERR set
            bus.read("Present_Position", "shoulder_pan")
    finally:
        bus.disconnect(disable_torque=False)


def test_torque_limit_caps_the_load_and_zero_drives_nothing() -> None:
    params = PhysicsParams()
    state = JointState(position=0.0)
    capped = Drive(torque_on=True, target=2000.0, speed_limit=0, acceleration=0, effort_limit=300)
    assert telemetry(state, capped, params).load == 300
    limp = Drive(torque_on=True, target=2000.0, speed_limit=0, acceleration=0, effort_limit=0)
    assert step(state, limp, 0.5, params).position == 0.0
    weak = step(state, capped, 0.1, params).position
    strong = step(state, Drive(torque_on=True, target=2000.0, speed_limit=0, acceleration=0), 0.1, params).position
    assert 0 < weak < strong


def test_a_torque_limit_under_the_overload_threshold_never_trips(so101_arm: RemoteArm) -> None:
    bus = a_feetech_bus(so101_arm)
    bus.connect()
    try:
        bus.write("Protection_Time", "shoulder_pan", 10)
        bus.enable_torque()
        bus.write("Torque_Limit", "shoulder_pan", 500)  # 50 % < Overload_Torque 80 %
        so101_arm.block("shoulder_pan")
        start = bus.read("Present_Position", "shoulder_pan", normalize=False)
        bus.write("Goal_Position", "shoulder_pan", start + 600, normalize=False)
        time.sleep(0.4)
        assert bus.read("Torque_Enable", "shoulder_pan") == 1
        assert bus.read("Present_Load", "shoulder_pan") <= 500
    finally:
        bus.disconnect(disable_torque=False)


def test_writing_baud_rate_moves_the_servo_off_the_hosts_line_speed(so101_arm: RemoteArm) -> None:
    bus = a_feetech_bus(so101_arm)
    bus.connect()
    try:
        bus.write("Lock", "gripper", 0)
        bus.write("Baud_Rate", "gripper", 4)  # 115 200 bit/s
        assert bus.ping("gripper") is None  # the host still talks at 1 Mbit/s: no servo there
        assert bus.ping("wrist_roll") is not None
        bus.set_baudrate(115_200)
        assert bus.ping("gripper") == 777  # at the servo's new rate it answers
        assert bus.ping("wrist_roll") is None
    finally:
        bus.disconnect(disable_torque=False)

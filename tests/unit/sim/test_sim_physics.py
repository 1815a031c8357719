"""Joint physics: bounded-speed motion toward the goal, telemetry that follows it."""

from __future__ import annotations

import pytest
from armnet_sim.physics import Drive, JointState, PhysicsParams, step, telemetry
from armnet_sim.servo import Servo, ServoCalibration

pytestmark = pytest.mark.unit

PARAMS = PhysicsParams(max_speed=1000.0)


def _drive(target: float, *, torque: bool = True, speed: float = 0, accel: int = 0) -> Drive:
    return Drive(torque_on=torque, target=target, speed_limit=speed, acceleration=accel)


def test_speed_is_bounded_by_the_maximum() -> None:
    state = step(JointState(position=0.0), _drive(2000), 0.5, PARAMS)
    assert state.position == pytest.approx(500.0)
    assert state.velocity == pytest.approx(1000.0)


def test_the_joint_stops_exactly_on_target() -> None:
    state = step(JointState(position=0.0), _drive(300), 1.0, PARAMS)
    assert state == JointState(position=300.0, velocity=0.0, temperature=state.temperature)


def test_goal_velocity_lowers_the_speed() -> None:
    state = step(JointState(position=0.0), _drive(2000, speed=200), 0.5, PARAMS)
    assert state.position == pytest.approx(100.0)


def test_acceleration_ramps_the_speed_up() -> None:
    ramped = step(JointState(position=0.0), _drive(2000, accel=10), 0.1, PARAMS)
    instant = step(JointState(position=0.0), _drive(2000), 0.1, PARAMS)
    assert 0 < ramped.position < instant.position


def test_with_acceleration_the_joint_still_settles_on_target() -> None:
    state = JointState(position=0.0)
    for _ in range(40):
        state = step(state, _drive(1000, accel=50), 0.05, PARAMS)
    assert state.position == 1000.0 and state.velocity == 0.0


def test_without_torque_the_joint_does_not_move() -> None:
    state = step(JointState(position=10.0), _drive(2000, torque=False), 1.0, PARAMS)
    assert state.position == 10.0 and state.velocity == 0.0


def test_load_and_current_rise_while_tracking_and_vanish_without_torque() -> None:
    moving = JointState(position=0.0, velocity=1000.0)
    busy = telemetry(moving, _drive(2000), PARAMS)
    idle = telemetry(JointState(position=2000.0), _drive(2000), PARAMS)
    limp = telemetry(moving, _drive(2000, torque=False), PARAMS)
    assert busy.load > idle.load > 0
    assert busy.current > idle.current
    assert busy.moving and not idle.moving
    assert limp.load == 0


def test_load_sign_follows_the_direction_of_effort() -> None:
    assert telemetry(JointState(position=500.0), _drive(0), PARAMS).load < 0


def test_sustained_load_heats_the_servo() -> None:
    state = JointState(position=0.0, temperature=PARAMS.ambient_temperature)
    for _ in range(60):
        state = step(state, _drive(4000, speed=1), 1.0, PARAMS)
    assert state.temperature > PARAMS.ambient_temperature + 1


def test_goal_is_clamped_to_the_position_limits() -> None:
    servo = Servo(1, calibration=ServoCalibration(homing_offset=0, range_min=1000, range_max=3000))
    servo.write(40, bytes([1]), now=0)
    servo.write(42, (3900).to_bytes(2, "little"), now=0)
    servo.advance(10.0)
    assert servo.get("Goal_Position") == 3900
    assert servo.present_position(now=10.0) == 3000


def test_servo_moves_in_the_offset_frame_and_reports_velocity_and_moving() -> None:
    servo = Servo(1, calibration=ServoCalibration(homing_offset=-300, range_min=0, range_max=4095))
    servo.write(40, bytes([1]), now=0)
    servo.write(42, (2500).to_bytes(2, "little"), now=0)
    servo.advance(0.05)
    assert servo.get("Moving") == 1
    assert servo.get("Present_Velocity") > 0
    servo.advance(5.0)
    assert servo.present_position(now=5.0) == 2500
    assert servo.get("Moving") == 0

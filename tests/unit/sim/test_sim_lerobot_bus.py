"""The real LeRobot 0.4.4 ``FeetechMotorsBus`` against the simulator, unmodified."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from armnet_sim import RemoteArm
from lerobot.motors import MotorCalibration
from lerobot.motors.feetech import OperatingMode

from .sim_lerobot_helpers import Steady, a_feetech_bus, lerobot_calibration, wait_until

pytestmark = pytest.mark.unit


@pytest.fixture
def bus(so101_arm: RemoteArm) -> Iterator[Steady]:
    """The real bus, connected; see ``Steady`` for why calls are retried on timeouts."""
    feetech = Steady(a_feetech_bus(so101_arm))
    feetech.connect()
    yield feetech
    if feetech.raw.port_handler.is_open:
        feetech.raw.port_handler.closePort()


def test_connect_passes_the_handshake_and_the_arm_is_calibrated(bus: Steady) -> None:
    assert bus.is_connected
    assert bus.is_calibrated


def test_read_calibration_returns_the_seeded_file(bus: Steady, so101_arm: RemoteArm) -> None:
    assert bus.read_calibration() == lerobot_calibration(so101_arm)


def test_write_calibration_lands_in_eeprom_sign_magnitude_encoded(
    bus: Steady, so101_arm: RemoteArm
) -> None:
    new = dict(lerobot_calibration(so101_arm))
    new["wrist_flex"] = MotorCalibration(
        id=4, drive_mode=0, homing_offset=-100, range_min=900, range_max=3100
    )
    bus.write_calibration(new)
    assert bus.read_calibration()["wrist_flex"] == new["wrist_flex"]
    assert so101_arm.register("wrist_flex", "Homing_Offset") == -100
    assert bus.read("Homing_Offset", "wrist_flex", normalize=False) == -100
    assert bus.is_calibrated


def test_sync_read_matches_the_simulated_state(bus: Steady, so101_arm: RemoteArm) -> None:
    assert bus.sync_read("Present_Position") == pytest.approx(so101_arm.normalized_positions())
    assert bus.sync_read("Present_Position", normalize=False) == so101_arm.positions()


def test_sync_write_goal_positions_converge(bus: Steady, so101_arm: RemoteArm) -> None:
    bus.enable_torque()
    goal = {"shoulder_pan": 30.0, "elbow_flex": -45.0, "gripper": 80.0}
    bus.sync_write("Goal_Position", goal)

    def arrived() -> bool:
        now = bus.sync_read("Present_Position")
        return all(abs(now[m] - v) < 0.2 for m, v in goal.items())

    assert wait_until(arrived)
    # Within 0.2 of the goal the servos may still run their last ticks (a loaded host read
    # them there): they stop, at the goal.
    assert wait_until(lambda: not so101_arm.is_moving())
    assert arrived()


def test_motion_is_rate_limited_not_instant(bus: Steady, so101_arm: RemoteArm) -> None:
    bus.enable_torque()
    bus.write("Goal_Velocity", "shoulder_pan", 200, normalize=False)  # ticks/s: ~6 s for the move
    start = so101_arm.positions()["shoulder_pan"]
    bus.write("Goal_Position", "shoulder_pan", 100.0)
    assert bus.read("Moving", "shoulder_pan") == 1
    assert bus.read("Present_Velocity", "shoulder_pan") > 0
    assert bus.read("Present_Load", "shoulder_pan") > 0
    assert abs(so101_arm.positions()["shoulder_pan"] - start) < 1100


def test_without_torque_goal_writes_do_not_move_the_arm(bus: Steady, so101_arm: RemoteArm) -> None:
    bus.disable_torque()
    before = so101_arm.positions()
    bus.sync_write("Goal_Position", {"shoulder_pan": 40.0})
    assert bus.read("Torque_Enable", "shoulder_pan") == 0
    assert so101_arm.positions() == before


def test_enable_and_disable_torque_write_torque_and_lock(bus: Steady, so101_arm: RemoteArm) -> None:
    bus.enable_torque()
    assert all(so101_arm.torque_enabled().values())
    assert {so101_arm.register(m, "Lock") for m in so101_arm.motors} == {1}
    bus.disable_torque()
    assert not any(so101_arm.torque_enabled().values())
    assert {so101_arm.register(m, "Lock") for m in so101_arm.motors} == {0}


def test_torque_disabled_context_restores_torque(bus: Steady, so101_arm: RemoteArm) -> None:
    bus.enable_torque()
    with bus.torque_disabled():
        bus.configure_motors()
        bus.write("Operating_Mode", "gripper", OperatingMode.POSITION.value)
        assert not any(so101_arm.torque_enabled().values())
    assert all(so101_arm.torque_enabled().values())
    assert so101_arm.register("gripper", "Maximum_Acceleration") == 254


def test_calibration_written_unlocked_survives_a_power_cycle(
    bus: Steady, so101_arm: RemoteArm
) -> None:
    bus.disable_torque()  # LeRobot's disable writes Lock = 0: EEPROM writes are saved
    bus.write("Min_Position_Limit", "shoulder_pan", 900, normalize=False)
    bus.enable_torque()  # Lock = 1: further EEPROM writes are volatile
    bus.write("Max_Position_Limit", "shoulder_pan", 3000, normalize=False)
    so101_arm.power_cycle()
    assert bus.read("Min_Position_Limit", "shoulder_pan", normalize=False) == 900
    assert bus.read("Max_Position_Limit", "shoulder_pan", normalize=False) == 3320
    assert bus.read("Torque_Enable", "shoulder_pan") == 0


def test_goal_beyond_the_calibrated_range_is_clamped(bus: Steady, so101_arm: RemoteArm) -> None:
    bus.enable_torque()
    bus.write("Goal_Position", "wrist_flex", 4000, normalize=False)
    assert wait_until(lambda: so101_arm.positions()["wrist_flex"] == 3220)


def test_negative_goal_velocity_is_sign_magnitude(bus: Steady, so101_arm: RemoteArm) -> None:
    bus.write("Goal_Velocity", "elbow_flex", -250, normalize=False)
    assert so101_arm.register("elbow_flex", "Goal_Velocity") == -250
    assert bus.read("Goal_Velocity", "elbow_flex", normalize=False) == -250


def test_half_turn_homing_centres_every_motor(bus: Steady, so101_arm: RemoteArm) -> None:
    bus.disable_torque()
    offsets = bus.set_half_turn_homings()
    assert set(offsets) == set(so101_arm.motors)
    assert set(bus.sync_read("Present_Position", normalize=False).values()) == {2047}


def test_disconnect_and_reconnect_reopen_the_pty(bus: Steady, so101_arm: RemoteArm) -> None:
    bus.disconnect()
    again = Steady(a_feetech_bus(so101_arm))
    again.connect()
    try:
        assert again.is_calibrated
    finally:
        again.disconnect()


def test_uncalibrated_servos_are_reported_as_not_calibrated(so101_arm: RemoteArm) -> None:
    feetech = Steady(a_feetech_bus(so101_arm))
    feetech.connect()
    try:
        feetech.reset_calibration()
        feetech.raw.calibration = lerobot_calibration(so101_arm)
        assert not feetech.is_calibrated
    finally:
        feetech.disconnect()


def test_ping_and_broadcast_ping_find_every_servo(bus: Steady) -> None:
    assert bus.ping("gripper") == 777
    assert bus.broadcast_ping() == {i: 777 for i in range(1, 7)}

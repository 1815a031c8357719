"""The register model of one STS3215: layout, encoding, EEPROM vs RAM, Lock."""

from __future__ import annotations

import pytest
from armnet_sim import control_table as ct
from armnet_sim.servo import Servo, ServoCalibration

pytestmark = pytest.mark.unit


def test_sign_magnitude_matches_lerobot_examples() -> None:
    assert ct.encode_sign_magnitude(-100, 11) == 0x0864
    assert ct.encode_sign_magnitude(-20, 11) == 0x0814
    assert ct.decode_sign_magnitude(0x0864, 11) == -100
    assert ct.decode_sign_magnitude(2047, 11) == 2047
    assert ct.decode_sign_magnitude(0x8005, 15) == -5


def test_sign_magnitude_rejects_values_that_do_not_fit() -> None:
    with pytest.raises(ValueError):
        ct.encode_sign_magnitude(2048, 11)


def test_a_fresh_servo_reports_model_777_its_id_and_factory_limits() -> None:
    servo = Servo(4)
    assert servo.read(3, 2, now=0) == bytes([0x09, 0x03])
    assert servo.read(5, 1, now=0) == bytes([4])
    assert servo.limits() == (0, 4095)
    assert servo.homing_offset() == 0
    assert servo.get("Response_Status_Level") == 1


def test_calibration_seeds_offset_and_limits_sign_magnitude_encoded() -> None:
    servo = Servo(
        1, calibration=ServoCalibration(homing_offset=-100, range_min=800, range_max=3300)
    )
    assert servo.read(31, 2, now=0) == bytes([0x64, 0x08])
    assert servo.limits() == (800, 3300)


def test_a_new_servo_rests_at_the_middle_of_its_range() -> None:
    servo = Servo(
        1, calibration=ServoCalibration(homing_offset=300, range_min=1000, range_max=3000)
    )
    assert servo.present_position(now=0) == 2000


def test_present_position_is_actual_minus_homing_offset() -> None:
    servo = Servo(1)
    servo.move_by_hand(1500, now=0)
    servo.write(31, ct.encode_sign_magnitude(-20, 11).to_bytes(2, "little"), now=0)
    assert servo.present_position(now=0) == 1520


def test_writes_to_read_only_registers_are_ignored() -> None:
    servo = Servo(1)
    servo.write(3, bytes([0x01, 0x00]), now=0)
    servo.write(56, bytes([0x00, 0x00]), now=0)
    assert servo.get("Model_Number") == 777
    assert servo.get("Present_Position") == 2048


def test_eeprom_written_while_locked_is_lost_on_power_cycle() -> None:
    servo = Servo(1)
    assert servo.get("Lock") == 1
    servo.write(9, (500).to_bytes(2, "little"), now=0)
    assert servo.limits()[0] == 500
    servo.power_cycle(now=1)
    assert servo.limits()[0] == 0


def test_eeprom_written_while_unlocked_survives_power_cycle() -> None:
    servo = Servo(1)
    servo.write(55, bytes([0]), now=0)
    servo.write(9, (500).to_bytes(2, "little"), now=0)
    servo.power_cycle(now=1)
    assert servo.limits()[0] == 500


def test_power_cycle_restores_ram_defaults_and_releases_torque() -> None:
    servo = Servo(1)
    servo.write(40, bytes([1]), now=0)
    servo.write(41, bytes([254]), now=0)
    servo.power_cycle(now=1)
    assert not servo.torque_on()
    assert servo.get("Acceleration") == 0
    assert servo.get("Torque_Limit") == servo.get("Max_Torque_Limit")


def test_goal_follows_the_joint_while_torque_is_off() -> None:
    servo = Servo(1)
    servo.move_by_hand(3000, now=0)
    assert servo.get("Goal_Position") == 3000
    servo.write(40, bytes([1]), now=0)
    servo.advance(1.0)
    assert servo.present_position(now=1.0) == 3000


def test_factory_reset_keeps_the_id_and_restores_limits() -> None:
    servo = Servo(3, calibration=ServoCalibration(homing_offset=10, range_min=100, range_max=200))
    servo.factory_reset(now=0)
    assert servo.servo_id == 3
    assert servo.limits() == (0, 4095)
    assert servo.homing_offset() == 0


def test_reads_past_the_table_are_zero_filled_to_the_requested_length() -> None:
    assert Servo(1).read(250, 10, now=0) == bytes(10)


def test_a_prepared_servo_holds_what_lerobots_setup_saved_through_a_power_cycle() -> None:
    configured = {"P_Coefficient": 16, "Max_Torque_Limit": 500, "Overload_Torque": 25}
    servo = Servo(6, calibration=ServoCalibration(homing_offset=0, range_min=100, range_max=4000),
                  configured=configured)
    servo.power_cycle(now=1)
    assert {name: servo.get(name) for name in configured} == configured
    assert servo.get("Torque_Limit") == 500  # loaded from Max_Torque_Limit at power-on
    assert Servo(6, configured=configured).get("P_Coefficient") == 32  # an unprepared servo: factory values


def test_a_setup_saves_eeprom_only() -> None:
    with pytest.raises(ValueError, match="Torque_Limit"):
        Servo(1, calibration=ServoCalibration(0, 0, 4095), configured={"Torque_Limit": 500})


def test_the_simulated_so101_is_a_prepared_cell_with_lerobots_gripper_limits() -> None:
    from armnet_sim.arm import SimulatedArm
    from armnet_sim.calibration import builtin_calibration

    arm = SimulatedArm(calibration=builtin_calibration("so101"))
    assert arm.register("gripper", "Max_Torque_Limit") == 500
    assert arm.register("gripper", "Protection_Current") == 250
    assert arm.register("elbow_flex", "Max_Torque_Limit") == 1000
    assert {arm.register(m, "P_Coefficient") for m in arm.motors} == {16}

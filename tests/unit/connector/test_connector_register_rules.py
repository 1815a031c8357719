"""The register policy and the config guards as pure rules (no bus): each rule stated once."""

from __future__ import annotations

import math

import pytest
from armnet_connector import ConnectorConfig
from armnet_connector.identity import CellMotor, JobMotor, motors_refusal, protocol_refusal
from armnet_connector.registers import (
    DEFAULT_BOUNDS,
    RESTORE_ORDER,
    STS3215,
    Rule,
    is_restored,
    write_refusal,
)
from pydantic import ValidationError

pytestmark = pytest.mark.unit


def refusal(register: str, value: int, **kwargs) -> str | None:
    kwargs.setdefault("interlock_held", False)
    return write_refusal("sts3215", register, "elbow_flex", value, **kwargs)


def test_bounded_registers_accept_only_values_inside_the_bounds() -> None:
    for register, (low, high) in DEFAULT_BOUNDS.items():
        assert refusal(register, low) is None and refusal(register, high) is None, register
        assert refusal(register, high + 1) is not None, register


def test_a_cells_bounds_replace_the_defaults() -> None:
    assert refusal("Goal_Velocity", 1500, bounds={"Goal_Velocity": (0, 2000)}) is None
    assert refusal("Goal_Velocity", 1500) is not None


EEPROM_REGISTERS = ["Return_Delay_Time", "Max_Torque_Limit", "P_Coefficient", "I_Coefficient", "D_Coefficient",
                    "Protection_Current", "Operating_Mode", "Overload_Torque", "Maximum_Acceleration"]


@pytest.mark.parametrize("register", EEPROM_REGISTERS)
def test_an_eeprom_register_is_written_only_with_the_value_the_servo_already_holds(register: str) -> None:
    assert refusal(register, 16, current=16) is None  # LeRobot's configure() on a prepared cell: a no-op
    changed = refusal(register, 16, current=32) or ""
    assert "EEPROM" in changed and "holds 32" in changed
    assert "EEPROM" in (refusal(register, 16) or "")  # a sync_write: the servo's value is not read


def test_max_torque_limit_is_eeprom_and_a_job_cannot_lower_it() -> None:
    why = refusal("Max_Torque_Limit", 200, current=1000) or ""
    assert "Max_Torque_Limit" in why and "EEPROM" in why and "holds 1000" in why


def test_every_rule_follows_where_the_register_lives_in_lerobots_sts3215_control_table() -> None:
    """EEPROM (addresses 0-39) and factory (80-86) are the cell's; only RAM (40-71) is tuned and restored."""
    from lerobot.motors.feetech.tables import MODEL_CONTROL_TABLE

    table = MODEL_CONTROL_TABLE["sts3215"]
    for register, rule in STS3215.items():
        address = table[register][0]
        persistent = address < 40 or address >= 80
        if persistent:
            assert rule.rule in (Rule.EEPROM, Rule.REFUSED), register
        else:
            assert rule.rule is not Rule.EEPROM, register
        assert is_restored("sts3215", register) == (rule.rule is Rule.BOUNDED), register
    assert {r for r, rule in STS3215.items() if rule.rule is Rule.BOUNDED} == set(DEFAULT_BOUNDS) == set(RESTORE_ORDER)


@pytest.mark.parametrize("register", ["ID", "Baud_Rate", "Lock", "Homing_Offset", "Min_Position_Limit", "Phase"])
def test_eeprom_identity_and_unlisted_registers_are_refused_by_name(register: str) -> None:
    assert register in (refusal(register, 0) or "")


def test_under_the_interlock_only_torque_off_passes() -> None:
    assert refusal("Torque_Enable", 0, interlock_held=True) is None
    for register, value in [("Torque_Enable", 1), ("Goal_Position", 2048), ("Lock", 0), ("Acceleration", 10)]:
        assert "interlock" in (refusal(register, value, interlock_held=True) or ""), register


def test_every_sts3215_register_lerobot_writes_in_configure_has_a_rule() -> None:
    for register in ["Return_Delay_Time", "Maximum_Acceleration", "Acceleration", "Operating_Mode",
                     "P_Coefficient", "I_Coefficient", "D_Coefficient", "Max_Torque_Limit",
                     "Protection_Current", "Overload_Torque", "Torque_Enable", "Goal_Position"]:
        assert register in STS3215


def test_a_job_motor_must_match_the_cells_id_model_and_unit() -> None:
    cell = {"gripper": CellMotor(6, "sts3215", "range_0_100")}
    assert motors_refusal({"gripper": JobMotor(6, "sts3215", "range_0_100")}, cell) is None
    assert "id 6" in (motors_refusal({"gripper": JobMotor(1, "sts3215", "range_0_100")}, cell) or "")
    assert motors_refusal({"gripper": JobMotor(6, "sts3215", "degrees")}, cell) is not None
    assert motors_refusal({}, cell) is None  # a bus that can only ping (LeRobot's scan_port)


def test_a_degrees_joint_also_takes_lerobots_default_body_unit_but_not_0_to_100() -> None:
    cell = {"elbow_flex": CellMotor(3, "sts3215", "degrees")}
    assert motors_refusal({"elbow_flex": JobMotor(3, "sts3215", "range_m100_100")}, cell) is None
    assert "'range_0_100'" in (motors_refusal({"elbow_flex": JobMotor(3, "sts3215", "range_0_100")}, cell) or "")


def test_the_cells_limit_is_converted_to_the_jobs_unit_through_ticks() -> None:
    from armnet_connector.config import MotorRange
    from armnet_connector.safety import MotorFacts, limit_in_write_units

    span = MotorRange(3, 1000, 3000)  # 2000 ticks: 10 ticks per -100..100 unit
    fact = MotorFacts("range_m100_100", span, span, limit_norm_mode="degrees")
    assert limit_in_write_units(30.0, fact, normalize=False) == pytest.approx(30 * 4095 / 360)
    assert limit_in_write_units(30.0, fact, normalize=True) == pytest.approx(30 * 4095 / 360 / 10)


def test_the_protocol_is_the_models() -> None:
    assert protocol_refusal(0, {"sts3215"}) is None
    assert protocol_refusal(1, {"sts3215"}) is not None
    assert protocol_refusal(False, {"sts3215"}) is not None  # a bool is not a protocol number


def arm(limit: object) -> dict[str, object]:
    return {"arms": {"arm": {"port": "/dev/null", "safetyLimit": limit}}}


@pytest.mark.parametrize("limit", [math.nan, math.inf, -5.0, 0, 0.0, "5", True, {}, {"elbow_flex": math.nan},
                                   {"elbow_flex": -1.0}, [5.0]])
def test_a_limit_that_is_nan_negative_zero_or_of_the_wrong_type_is_rejected_at_load(limit: object) -> None:
    with pytest.raises(ValidationError) as raised:
        ConnectorConfig.model_validate(arm(limit))
    assert "safetyLimit" in str(raised.value)


def test_a_positive_number_or_per_motor_mapping_is_a_limit() -> None:
    assert ConnectorConfig.model_validate(arm(5)).arms["arm"].safety_limit == 5
    assert ConnectorConfig.model_validate(arm({"gripper": 2.5})).arms["arm"].safety_limit == {"gripper": 2.5}


def test_safety_policy_is_clamp_by_default_and_only_clamp_or_trip() -> None:
    assert ConnectorConfig.model_validate(arm(5)).safety_policy == "clamp"
    assert ConnectorConfig.model_validate({**arm(5), "safetyPolicy": "trip"}).safety_policy == "trip"
    with pytest.raises(ValidationError):
        ConnectorConfig.model_validate({**arm(5), "safetyPolicy": "ignore"})


def test_register_bounds_name_bounded_registers_in_order() -> None:
    with pytest.raises(ValidationError, match="not a bounded register"):
        ConnectorConfig.model_validate({**arm(5), "registerBounds": {"ID": [0, 10]}})
    with pytest.raises(ValidationError, match="above upper bound"):
        ConnectorConfig.model_validate({**arm(5), "registerBounds": {"Goal_Velocity": [10, 0]}})


def test_register_bounds_for_an_eeprom_register_say_it_takes_none() -> None:
    with pytest.raises(ValidationError, match="'P_Coefficient' is in the servos' EEPROM"):
        ConnectorConfig.model_validate({**arm(5), "registerBounds": {"P_Coefficient": [8, 32]}})

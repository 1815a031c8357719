"""The restore's pure parts: where the restored registers sit, what is written back, what the read-back says."""

from __future__ import annotations

import pytest
from armnet_connector.restore import (
    RegisterLedger,
    Restored,
    judge_restore,
    restore_block,
    restore_plan,
)

pytestmark = pytest.mark.unit

NAMES = {3: "elbow_flex", 6: "gripper"}
FOUND = {"Acceleration": 0, "Goal_Time": 0, "Goal_Velocity": 0, "Torque_Limit": 1000}


def sts3215_block():
    from lerobot.motors.feetech.tables import MODEL_CONTROL_TABLE, MODEL_ENCODING_TABLE

    return restore_block("sts3215", MODEL_CONTROL_TABLE["sts3215"], MODEL_ENCODING_TABLE["sts3215"])


def test_the_sts3215s_restored_registers_are_one_nine_byte_read_from_acceleration_to_torque_limit() -> None:
    block = sts3215_block()
    assert (block.start, block.length) == (41, 9)  # no LeRobot read asks for 9 bytes
    assert set(block.fields) == set(FOUND)


def test_a_block_decodes_little_endian_with_goal_velocitys_sign_bit() -> None:
    #            41  42 43 (goal) 44 45  46    47          48    49
    data = [254, 0, 8, 0, 0, 100, 0x80, 0xF4, 0x01]
    assert sts3215_block().decode(data) == {
        "Acceleration": 254, "Goal_Time": 0, "Goal_Velocity": -100, "Torque_Limit": 500}


def test_only_registers_the_job_left_changed_are_written_back_torque_limit_first() -> None:
    pending = {3: {"Acceleration": 0, "Torque_Limit": 1000}, 6: {"Torque_Limit": 500}}
    held = {3: {**FOUND, "Acceleration": 10, "Torque_Limit": 300}, 6: {**FOUND, "Torque_Limit": 500}}
    plan = restore_plan(pending, held)
    assert plan == {"Torque_Limit": {3: 1000}, "Acceleration": {3: 0}}
    assert list(plan) == ["Torque_Limit", "Acceleration"]


def test_a_servo_that_could_not_be_read_is_not_written() -> None:
    assert restore_plan({3: {"Torque_Limit": 1000}}, {3: None}) == {}


def test_the_outcome_lists_what_was_put_back_and_names_what_was_not() -> None:
    pending = {3: {"Torque_Limit": 1000, "Acceleration": 0}, 6: {"Torque_Limit": 500}}
    before = {3: {**FOUND, "Torque_Limit": 300, "Acceleration": 10}, 6: None}
    after = {3: {**FOUND, "Acceleration": 10}, 6: None}
    outcome = judge_restore(pending, before, after, NAMES)
    assert outcome.restored == (Restored("elbow_flex", "Torque_Limit", 300, 1000),)
    assert outcome.settled == ((3, "Torque_Limit"),)
    assert outcome.failures == (  # in the restore's order: Torque_Limit first
        "gripper (id 6): Torque_Limit was not written back to 500 (the value the job found): the servo did not "
        "answer, so it could not be read and held first",
        "elbow_flex (id 3): Acceleration is 10 after the restore, not 0 (the value the job found)",
    )


def test_a_register_already_back_is_settled_without_being_reported() -> None:
    outcome = judge_restore({3: {"Torque_Limit": 1000}}, {3: FOUND}, {3: FOUND}, NAMES)
    assert outcome.restored == () and outcome.failures == () and outcome.settled == ((3, "Torque_Limit"),)


def test_the_ledger_keeps_the_first_snapshot_and_forgets_a_register_once_settled() -> None:
    ledger = RegisterLedger()
    ledger.keep_snapshot(3, FOUND)
    ledger.keep_snapshot(3, {**FOUND, "Torque_Limit": 300})  # a later read never replaces what the job found
    ledger.touch(3, "Torque_Limit")
    assert ledger.has_snapshot(3) and not ledger.has_snapshot(6)
    assert ledger.pending() == {3: {"Torque_Limit": 1000}}  # only what the job wrote
    ledger.settle(3, "Torque_Limit")
    assert ledger.pending() == {}

"""Motor identity, units, limits and protocol belong to the cell.

Each test drives the real connector, the real LeRobot bus and scservo_sdk on the
simulated SO-101, through the SDK's remote bus as a job would.
"""

from __future__ import annotations

import pytest
from armnet_runtime.errors import RemoteCallError
from armnet_runtime.lerobot.remote_feetech import RemoteFeetechMotorsBus

pytestmark = pytest.mark.unit


@pytest.fixture
def connector(sim_cell, make_connector, cell_config):
    return make_connector(cell_config(sim_cell))


def refusal(connector, motors, **kwargs) -> RemoteCallError:
    with pytest.raises(RemoteCallError) as raised:
        RemoteFeetechMotorsBus(port=connector.robot_endpoint, motors=motors, **kwargs)
    assert raised.value.error_type == "NotAllowed", raised.value
    return raised.value


def test_a_motor_name_aliased_to_another_servos_id_is_refused_naming_what_the_cell_has(connector) -> None:
    from lerobot.motors import Motor, MotorNormMode

    # The aliasing bypass: servo 1 (shoulder_pan) named wrist_roll, to borrow wrist_roll's limits.
    error = refusal(connector, {"wrist_roll": Motor(1, "sts3215", MotorNormMode.DEGREES)})
    assert "wrist_roll" in str(error) and "id 5" in str(error)


def test_a_degrees_joint_declared_in_another_unit_is_refused(connector) -> None:
    from lerobot.motors import Motor, MotorNormMode

    error = refusal(connector, {"elbow_flex": Motor(3, "sts3215", MotorNormMode.RANGE_0_100)})
    assert "elbow_flex" in str(error) and "'degrees'" in str(error)


def test_a_motor_the_cell_does_not_have_is_refused(connector) -> None:
    from lerobot.motors import Motor, MotorNormMode

    error = refusal(connector, {"elbow": Motor(7, "sts3215", MotorNormMode.DEGREES)})
    assert "'elbow' is not a motor of this cell" in str(error)


def test_a_protocol_other_than_the_models_is_refused_and_the_sdk_byte_order_is_unchanged(
    connector, motors, sim_cell
) -> None:
    import scservo_sdk.scservo_def as scs_def

    bus = RemoteFeetechMotorsBus(port=connector.robot_endpoint, motors=motors)
    bus.connect()
    before = bus.sync_read("Present_Position", normalize=False)
    assert scs_def.SCS_END == 0
    error = refusal(connector, motors, protocol_version=1)
    assert "protocol_version=1" in str(error)
    assert scs_def.SCS_END == 0  # the refused create never reached scservo_sdk
    assert bus.sync_read("Present_Position", normalize=False) == before == sim_cell.arm.positions()
    bus.disconnect()


def test_a_calibration_other_than_the_cells_is_refused(connector, motors, calibration) -> None:
    import dataclasses

    widened = dict(calibration)
    widened["wrist_flex"] = dataclasses.replace(calibration["wrist_flex"], range_min=0, range_max=4095)
    error = refusal(connector, motors, calibration=widened)
    assert "wrist_flex" in str(error) and "ctx.cell.calibration_dir" in str(error)


def test_a_bus_without_calibration_gets_the_cells_and_is_calibrated(connector, motors, calibration) -> None:
    bus = RemoteFeetechMotorsBus(port=connector.robot_endpoint, motors=motors)
    bus.connect()
    assert bus.calibration == calibration
    assert bus.is_calibrated
    bus.disconnect()


def test_a_subset_of_the_cells_motors_with_the_same_identity_is_served(connector, sim_cell) -> None:
    from lerobot.motors import Motor, MotorNormMode

    bus = RemoteFeetechMotorsBus(
        port=connector.robot_endpoint, motors={"gripper": Motor(6, "sts3215", MotorNormMode.RANGE_0_100)}
    )
    bus.connect()
    assert set(bus.sync_read("Present_Position")) == {"gripper"}
    bus.disconnect()


def test_limits_apply_to_the_servo_the_cell_names_not_the_jobs_name(connector, motors, sim_cell) -> None:
    """A job cannot borrow another motor's limit: every name is the cell's own servo."""
    bus = RemoteFeetechMotorsBus(port=connector.robot_endpoint, motors=motors)
    bus.connect()
    bus.enable_torque()
    present = bus.sync_read("Present_Position", normalize=False)
    bus.sync_write("Goal_Position", {"shoulder_pan": present["shoulder_pan"] + 1000}, normalize=False)
    limit_ticks = 30.0 * 4095 / 360  # the cell's 30 degrees, in ticks
    # A read on the same line: the simulator has applied the (reply-less) sync_write before it answers.
    step = bus.read("Goal_Position", "shoulder_pan", normalize=False) - present["shoulder_pan"]
    assert 0 < step <= limit_ticks + 1
    bus.disconnect()


def test_lerobots_default_body_unit_is_served_with_the_cells_limit_in_ticks(connector, sim_cell) -> None:
    """SO101FollowerConfig's default (use_degrees=False) declares the body in -100..100."""
    from lerobot.motors import Motor, MotorNormMode

    bus = RemoteFeetechMotorsBus(
        port=connector.robot_endpoint, motors={"elbow_flex": Motor(3, "sts3215", MotorNormMode.RANGE_M100_100)}
    )
    bus.connect()
    bus.enable_torque()
    before = sim_cell.arm.positions()["elbow_flex"]
    present = bus.sync_read("Present_Position")["elbow_flex"]
    bus.sync_write("Goal_Position", {"elbow_flex": present + 90.0})  # far, in -100..100 units
    step = bus.read("Goal_Position", "elbow_flex", normalize=False) - before
    assert 0 < step <= 30.0 * 4095 / 360 + 2  # the cell's 30 degrees, whatever the job's unit
    bus.disconnect()

"""Injected faults make the real LeRobot bus fail the way real hardware makes it fail.

Setup steps go through ``Steady`` (retries when the client itself missed its
deadline); every call that is expected to fail uses the bare bus (``.raw``).
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from armnet_sim import RemoteArm

from .sim_lerobot_helpers import Steady, a_feetech_bus

pytestmark = pytest.mark.unit


@pytest.fixture
def bus(so101_arm: RemoteArm) -> Iterator[Steady]:
    feetech = Steady(a_feetech_bus(so101_arm))
    feetech.connect()
    yield feetech
    so101_arm.clear_faults()
    feetech.raw.port_handler.closePort()


def test_an_unplugged_servo_fails_connect_with_missing_ids(so101_arm: RemoteArm) -> None:
    so101_arm.unplug("wrist_roll")
    feetech = a_feetech_bus(so101_arm)
    with pytest.raises(RuntimeError, match="Missing motor IDs") as excinfo:
        feetech.connect()
    assert "- 5 (expected model: 777)" in str(excinfo.value)
    feetech.port_handler.closePort()


def test_unplugging_mid_session_fails_sync_read(bus: Steady, so101_arm: RemoteArm) -> None:
    so101_arm.unplug("elbow_flex")
    with pytest.raises(ConnectionError, match="no status packet"):
        bus.raw.sync_read("Present_Position")
    so101_arm.plug("elbow_flex")
    assert set(bus.sync_read("Present_Position")) == set(so101_arm.motors)


def test_a_corrupt_reply_raises_connection_error(bus: Steady, so101_arm: RemoteArm) -> None:
    so101_arm.corrupt_replies("shoulder_lift")
    with pytest.raises(ConnectionError, match="Incorrect status packet"):
        bus.raw.read("Present_Position", "shoulder_lift")
    with pytest.raises(ConnectionError, match="Incorrect status packet"):
        bus.raw.sync_read("Present_Position")


def test_overload_makes_reads_and_writes_raise_but_sync_read_ignores_it(
    bus: Steady, so101_arm: RemoteArm
) -> None:
    so101_arm.overload("gripper")
    with pytest.raises(RuntimeError, match="Overload"):
        bus.raw.read("Present_Position", "gripper")
    with pytest.raises(RuntimeError, match="Overload"):
        bus.raw.write("Torque_Enable", "gripper", 1)
    # GroupSyncRead never looks at the ERR byte (docs/reference/feetech-lerobot.md, §1).
    assert "gripper" in bus.sync_read("Present_Position")
    assert bus.read("Status", "shoulder_pan") == 0


def test_an_overloaded_servo_fails_the_connect_handshake(so101_arm: RemoteArm) -> None:
    so101_arm.overload("shoulder_pan")
    feetech = a_feetech_bus(so101_arm)
    with pytest.raises(RuntimeError, match="Missing motor IDs"):
        feetech.connect()
    feetech.port_handler.closePort()


def test_moderate_latency_is_tolerated(so101_arm: RemoteArm) -> None:
    so101_arm.set_latency_ms(5)
    feetech = Steady(a_feetech_bus(so101_arm))
    feetech.connect()
    try:
        assert feetech.is_calibrated
    finally:
        feetech.disconnect(disable_torque=False)


def test_latency_beyond_lerobots_timeout_fails_connect(so101_arm: RemoteArm) -> None:
    so101_arm.set_latency_ms(80)
    feetech = a_feetech_bus(so101_arm)
    with pytest.raises(RuntimeError, match="Missing motor IDs"):
        feetech.connect()
    feetech.port_handler.closePort()


def test_a_transient_checksum_error_is_recovered_by_lerobots_retry(
    bus: Steady, so101_arm: RemoteArm
) -> None:
    so101_arm.corrupt_replies("elbow_flex", count=1)
    with pytest.raises(ConnectionError, match="Incorrect status packet"):
        bus.raw.read("Present_Position", "elbow_flex", normalize=False)
    so101_arm.corrupt_replies("elbow_flex", count=1)
    value = bus.read("Present_Position", "elbow_flex", normalize=False, num_retry=1)
    assert value == so101_arm.positions()["elbow_flex"]


def test_a_lost_write_ack_is_retried_and_the_write_still_applies(
    bus: Steady, so101_arm: RemoteArm
) -> None:
    so101_arm.drop_replies("wrist_flex", count=1)
    bus.raw.write("Acceleration", "wrist_flex", 77, num_retry=1)
    assert so101_arm.register("wrist_flex", "Acceleration") == 77

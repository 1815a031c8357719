"""The real ``scservo_sdk`` (feetech-servo-sdk) against the simulator over a pty."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import scservo_sdk as scs
from armnet_sim import ErrorBit, RemoteArm, SimulatedCellProcess

from .sim_lerobot_helpers import wait_until

pytestmark = pytest.mark.unit


def txrx(fn: Callable[..., Any], port: scs.PortHandler, *args: Any) -> Any:
    """Call ``fn(port, *args)``, retrying when the client missed its own deadline.

    The SDK's deadline is ~34 ms here (no LeRobot patch); on a loaded machine the
    test process alone can be descheduled that long. The reply then arrives after
    the SDK gave up, so the input buffer is flushed before retrying (the SDK never
    flushes it). Fault tests call the SDK directly.
    """
    for _ in range(5):
        result = fn(port, *args)
        code = result if isinstance(result, int) else result[-2]
        if code != scs.COMM_RX_TIMEOUT:
            return result
        time.sleep(0.06)
        port.ser.reset_input_buffer()
    return result


@pytest.fixture
def port(so101_arm: RemoteArm) -> Iterator[scs.PortHandler]:
    handler = scs.PortHandler(so101_arm.port)
    assert handler.openPort()
    yield handler
    handler.closePort()


@pytest.fixture
def packets() -> scs.protocol_packet_handler:
    return scs.PacketHandler(0)


def test_ping_returns_the_sts3215_model_number(port, packets) -> None:
    assert txrx(packets.ping, port, 1) == (777, scs.COMM_SUCCESS, 0)


def test_read_and_write_one_register(port, packets) -> None:
    assert txrx(packets.write1ByteTxRx, port, 3, 41, 200) == (scs.COMM_SUCCESS, 0)
    assert txrx(packets.read1ByteTxRx, port, 3, 41) == (200, scs.COMM_SUCCESS, 0)


def test_firmware_version_is_the_same_on_every_servo(port, packets) -> None:
    versions = {
        (txrx(packets.read1ByteTxRx, port, i, 0)[0], txrx(packets.read1ByteTxRx, port, i, 1)[0])
        for i in range(1, 7)
    }
    assert len(versions) == 1


def test_group_sync_read_returns_every_position(port, packets, so101_arm: RemoteArm) -> None:
    group = scs.GroupSyncRead(port, packets, 56, 2)
    for servo_id in (6, 1, 3):
        assert group.addParam(servo_id)
    assert txrx(lambda _port: group.txRxPacket(), port) == scs.COMM_SUCCESS
    positions = so101_arm.positions()
    assert group.getData(6, 56, 2) == positions["gripper"]
    assert group.getData(1, 56, 2) == positions["shoulder_pan"]
    assert group.getData(3, 56, 2) == positions["elbow_flex"]


def test_group_sync_write_moves_the_servos(port, packets, so101_arm: RemoteArm) -> None:
    for servo_id in (1, 2):
        assert txrx(packets.write1ByteTxRx, port, servo_id, 40, 1)[0] == scs.COMM_SUCCESS
    group = scs.GroupSyncWrite(port, packets, 42, 2)
    group.addParam(1, [0x00, 0x08])  # 2048
    group.addParam(2, [0xD0, 0x07])  # 2000
    assert group.txPacket() == scs.COMM_SUCCESS
    # SYNC_WRITE has no reply, so the simulator applies it a moment after txPacket returns.
    assert wait_until(lambda: so101_arm.positions()["shoulder_pan"] == 2048)
    assert so101_arm.goal_positions()["shoulder_lift"] == 2000
    assert wait_until(lambda: so101_arm.positions()["shoulder_lift"] == 2000)


def test_an_unplugged_servo_times_out(port, packets, so101_arm: RemoteArm) -> None:
    so101_arm.unplug("elbow_flex")
    assert packets.ping(port, 3)[1] == scs.COMM_RX_TIMEOUT
    so101_arm.plug("elbow_flex")
    assert txrx(packets.ping, port, 3)[1] == scs.COMM_SUCCESS


def test_a_corrupt_reply_is_reported_as_corrupt(port, packets, so101_arm: RemoteArm) -> None:
    so101_arm.corrupt_replies("wrist_flex")
    assert packets.read2ByteTxRx(port, 4, 56)[1] == scs.COMM_RX_CORRUPT


def test_overload_is_reported_in_the_error_byte(port, packets, so101_arm: RemoteArm) -> None:
    so101_arm.overload("gripper")
    _, result, error = packets.read2ByteTxRx(port, 6, 56)
    assert result == scs.COMM_SUCCESS
    assert error == ErrorBit.OVERLOAD
    assert packets.getRxPacketError(error) == "[RxPacketError] Overload error!"


def test_the_port_can_be_closed_and_reopened(port, packets) -> None:
    port.closePort()
    assert port.openPort()
    assert txrx(packets.ping, port, 5)[1] == scs.COMM_SUCCESS


def test_the_stable_symlink_is_a_usable_port(tmp_path: Path) -> None:
    with SimulatedCellProcess("so101", link_dir=tmp_path) as cell:
        link = tmp_path / "so101-arm"
        assert cell.arm.port == str(link) and link.is_symlink()
        handler = scs.PortHandler(str(link))
        assert handler.openPort()
        try:
            assert txrx(scs.PacketHandler(0).ping, handler, 2)[1] == scs.COMM_SUCCESS
        finally:
            handler.closePort()
    assert not link.exists()

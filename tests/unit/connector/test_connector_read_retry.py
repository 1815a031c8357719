"""Lost servo replies: the connector asks again for reads, never for writes.

The simulator's fault injection (``drop_replies``) loses a servo's next status
packets, as a loaded machine does when a reply misses LeRobot's ~50 ms timeout.
"""

from __future__ import annotations

import pytest
from armnet_connector.restore import READ_RETRIES
from armnet_connector.retry import (
    MAX_RETRIES,
    is_lost_reply,
    is_read,
    is_retried,
    retry_delays,
)
from armnet_runtime.lerobot.remote_feetech import RemoteFeetechMotorsBus
from lerobot.utils.errors import DeviceAlreadyConnectedError, DeviceNotConnectedError

pytestmark = pytest.mark.unit


@pytest.fixture
def connector(sim_cell, make_connector, cell_config):
    return make_connector(cell_config(sim_cell))


@pytest.fixture
def remote(connector, motors, calibration):
    bus = RemoteFeetechMotorsBus(port=connector.robot_endpoint, motors=motors, calibration=calibration)
    yield bus
    if bus.is_connected:
        bus.disconnect(disable_torque=False)


def test_a_sync_read_that_lost_one_reply_succeeds_and_counts_a_retry(remote, sim_cell, connector) -> None:
    remote.connect()
    expected = sim_cell.arm.normalized_positions()
    before = connector.counters.bus_retries  # a loaded host may have cost the handshake a retry
    sim_cell.arm.drop_replies("elbow_flex", 1)
    values = remote.sync_read("Present_Position")
    assert connector.counters.bus_retries - before >= 1
    assert values["elbow_flex"] == pytest.approx(expected["elbow_flex"], abs=0.5)
    # The late reply was not left behind for the next transaction to swallow.
    assert remote.read("Present_Position", "wrist_flex") == pytest.approx(expected["wrist_flex"], abs=0.5)


def test_a_connect_handshake_that_lost_a_ping_reply_succeeds(remote, sim_cell, connector) -> None:
    sim_cell.arm.drop_replies("shoulder_lift", 1)
    remote.connect()
    assert remote.is_connected
    assert connector.counters.bus_retries >= 1
    assert set(remote.sync_read("Present_Position")) == set(sim_cell.arm.motors)


def test_a_connect_handshake_waits_longer_between_retries_than_a_loops_read() -> None:
    """A starved connector's handshake gets about 2.8 s to hear its servos; a loop's read about 0.5 s."""
    assert len(retry_delays("connect")) > MAX_RETRIES
    assert sum(retry_delays("connect")) >= 2.5
    assert retry_delays("sync_read") == retry_delays("read")
    assert len(retry_delays("sync_read")) == MAX_RETRIES
    assert sum(retry_delays("sync_read")) <= 0.6


def test_a_connect_handshake_that_lost_every_ping_reply_for_a_while_succeeds(remote, sim_cell, connector) -> None:
    # More than a loop's read would retry, and one fewer than the handshake's retries: dropping
    # as many as it retries left no attempt for a reply a loaded host delays by itself (this
    # test failed so while the suite's image builds ran beside it).
    dropped = MAX_RETRIES + 1
    assert dropped < len(retry_delays("connect"))
    sim_cell.arm.drop_replies("shoulder_pan", dropped)
    remote.connect()
    assert remote.is_connected
    assert connector.counters.bus_retries >= dropped  # a loaded host may lose one more


def test_a_read_that_keeps_failing_raises_after_the_retries(remote, sim_cell, connector) -> None:
    remote.connect()
    before = connector.counters.bus_retries
    sim_cell.arm.drop_replies("gripper", MAX_RETRIES + 5)
    with pytest.raises(ConnectionError, match="status packet"):
        remote.read("Present_Position", "gripper")
    assert connector.counters.bus_retries - before == MAX_RETRIES
    sim_cell.arm.clear_faults("gripper")
    assert "gripper" in remote.sync_read("Present_Position")


def test_a_register_write_that_lost_its_acknowledgement_is_sent_again_and_applied(
        remote, sim_cell, connector) -> None:
    """An absolute register write applied twice leaves the servo as applied once."""
    remote.connect()
    assert remote.read("Response_Status_Level", "wrist_roll") == 1  # the servo acknowledges writes
    remote.write("Torque_Enable", "wrist_roll", 0)
    before = connector.counters.bus_retries
    sim_cell.arm.drop_replies("wrist_roll", 1)
    remote.write("Torque_Enable", "wrist_roll", 1)
    assert connector.counters.bus_retries - before >= 1
    assert sim_cell.arm.register("wrist_roll", "Torque_Enable") == 1


def test_a_write_that_keeps_losing_its_acknowledgement_raises_after_the_retries(remote, sim_cell, connector) -> None:
    remote.connect()
    before = connector.counters.bus_retries
    sim_cell.arm.drop_replies("wrist_roll", MAX_RETRIES + 5)
    with pytest.raises(ConnectionError, match="status packet"):
        remote.write("Torque_Enable", "wrist_roll", 1)
    assert connector.counters.bus_retries - before == MAX_RETRIES


def test_a_torque_switch_that_lost_an_acknowledgement_is_asked_again_and_torque_ends_on(
        remote, sim_cell, connector) -> None:
    """Torque on writes the same values however often it runs: a lost reply must not fail the job."""
    remote.connect()
    remote.disable_torque()
    before = connector.counters.bus_retries
    sim_cell.arm.drop_replies("elbow_flex", 1)
    remote.enable_torque()
    assert connector.counters.bus_retries - before >= 1
    assert all(sim_cell.arm.register(m, "Torque_Enable") == 1 for m in sim_cell.arm.motors)


def test_torque_disabled_whose_switches_lost_an_acknowledgement_asks_again_and_leaves_torque_on(
        remote, sim_cell, connector) -> None:
    """LeRobot's SO follower wraps configure in ``bus.torque_disabled()``: a CI run failed a job on its lost ack."""
    remote.connect()
    before = connector.counters.bus_retries
    sim_cell.arm.drop_replies("shoulder_pan", 1)  # the disable's acknowledgement
    with remote.torque_disabled():
        assert all(sim_cell.arm.register(m, "Torque_Enable") == 0 for m in sim_cell.arm.motors)
        sim_cell.arm.drop_replies("gripper", 1)  # and the enable's at the exit
    assert connector.counters.bus_retries - before >= 2
    assert all(sim_cell.arm.register(m, "Torque_Enable") == 1 for m in sim_cell.arm.motors)


def test_configure_motors_that_lost_an_acknowledgement_is_run_again_and_configures_every_motor(
        remote, sim_cell, connector) -> None:
    """LeRobot's SO follower calls it in connect, with no retry of its own: a loaded CI run failed a job on it."""
    remote.connect()
    before = connector.counters.bus_retries
    # The read of the value a write replaces has its own retries: one more lost reply fails the call once.
    sim_cell.arm.drop_replies("shoulder_pan", READ_RETRIES + 1)
    remote.configure_motors()
    assert connector.counters.bus_retries - before >= 1
    assert all(sim_cell.arm.register(m, "Return_Delay_Time") == 0 for m in sim_cell.arm.motors)
    assert all(sim_cell.arm.register(m, "Acceleration") == 254 for m in sim_cell.arm.motors)


def test_a_calibration_jobs_write_calibration_that_lost_an_acknowledgement_is_run_again(
        sim_cell, make_connector, cell_config, motors, calibration) -> None:
    """Absolute values, one write each per motor: a loaded CI run failed a calibration job on a lost ack."""
    import dataclasses

    connector = make_connector(cell_config(sim_cell, allowCalibrationJobs=True))
    job = RemoteFeetechMotorsBus(port=connector.robot_endpoint, motors=motors, calibration=calibration)
    job.connect()
    moved = {name: dataclasses.replace(c, range_max=c.range_max - 10) for name, c in calibration.items()}
    before = connector.counters.bus_retries
    sim_cell.arm.drop_replies("elbow_flex", 1)
    job.write_calibration(moved)
    assert connector.counters.bus_retries - before >= 1
    assert job.read_calibration() == moved
    job.disconnect()  # the connector puts the cell's calibration back


def test_which_calls_and_failures_are_retried() -> None:
    assert is_retried("FeetechMotorsBus", "configure_motors")
    assert is_retried("FeetechMotorsBus", "enable_torque")
    assert is_retried("FeetechMotorsBus", "disable_torque")
    assert is_retried("FeetechMotorsBus", "sync_read")
    assert is_retried("FeetechMotorsBus", "write")
    assert is_retried("FeetechMotorsBus", "write_calibration")
    assert is_retried("FeetechMotorsBus", "reset_calibration")
    assert not is_retried("FeetechMotorsBus", "set_half_turn_homings")  # reads what its own writes moved
    assert not is_retried("FeetechMotorsBus", "sync_write")
    assert is_read("FeetechMotorsBus", "sync_read", kind="call")
    assert is_read("FeetechMotorsBus", "is_calibrated", kind="get")
    assert not is_read("FeetechMotorsBus", "sync_write", kind="call")
    assert not is_read("FeetechMotorsBus", "write", kind="call")
    assert not is_read("OpenCVCamera", "read", kind="call")
    assert is_lost_reply(ConnectionError("Failed to sync read. [TxRxResult] There is no status packet!"))
    assert is_lost_reply(TimeoutError("no reply"))
    assert not is_lost_reply(DeviceNotConnectedError("not connected"))
    assert not is_lost_reply(DeviceAlreadyConnectedError("already connected"))
    assert not is_lost_reply(RuntimeError("[RxPacketError] Overload error!"))
    assert not is_lost_reply(RuntimeError("motor check failed:\nMissing motor IDs:\n - 2"))
    assert is_lost_reply(RuntimeError("motor check failed:\nMissing motor IDs:\n - 2"), connecting=True)


def test_an_index_error_from_the_servo_sdk_is_a_reply_cut_short_and_one_from_elsewhere_is_not() -> None:
    """scservo_sdk indexes a truncated status packet instead of reporting it (seen in a loaded CI
    run: ``connect`` failed with IndexError); an IndexError of any other code is a bug, not a retry."""
    import scservo_sdk

    def raised_in(filename: str) -> IndexError:
        try:
            exec(compile("[][0]", filename, "exec"))  # noqa: S102 - a frame that lives in that file
        except IndexError as exc:
            return exc
        raise AssertionError("no IndexError")

    assert is_lost_reply(raised_in(scservo_sdk.__file__))
    assert is_lost_reply(raised_in(scservo_sdk.__file__), connecting=True)
    assert not is_lost_reply(raised_in(__file__))
    assert not is_lost_reply(IndexError("no traceback"))


def test_a_write_retry_is_checked_again_and_an_interlock_tripped_meanwhile_ends_it() -> None:
    """The guard ran before the first attempt; a trip during the wait must hold for the retry too."""
    from armnet_connector.errors import RequestError
    from armnet_connector.hardware import DeviceLock, Handle
    from armnet_connector.retry import with_read_retry

    attempts: list[int] = []
    tripped: list[bool] = []

    class Bus:
        def write(self) -> None:
            attempts.append(1)
            raise ConnectionError("Failed to write 'Goal_Position': There is no status packet!")

    def check_again() -> None:
        if tripped:
            raise RequestError("SafetyLimitExceeded", "the interlock is tripped")

    handle = Handle("FeetechMotorsBus", Bus(), DeviceLock("test"))
    with pytest.raises(RequestError, match="interlock"):
        with_read_retry(handle, "write", handle.obj.write, on_retry=lambda: None, before_retry=check_again,
                        sleep=lambda _s: tripped.append(True))  # the interlock trips while the retry waits
    assert len(attempts) == 1

"""Rest, reset and torque off go through the cell's own bus; every bus call and the
connector's stop end in bounded time; one handle's close does not drop the arm under another.

All on the real FeetechMotorsBus talking to the simulated SO-101, checked on the simulator's side.
"""

from __future__ import annotations

import threading
import time

import pytest
from lerobot.motors import Motor, MotorNormMode

pytestmark = pytest.mark.unit

REST = {"shoulder_pan": 1500, "elbow_flex": 1800, "wrist_roll": 2600, "gripper": 2100}
TOLERANCE = 25


def wait_until(predicate, timeout: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.02)
    return predicate()


def at_rest(sim_cell) -> bool:
    positions = sim_cell.arm.positions()
    return all(abs(positions[m] - goal) <= TOLERANCE for m, goal in REST.items())


def rest_config(cell_config, sim_cell, **overrides):
    """The simulated cell's config with the arm's rest pose set to ``REST``."""
    config = cell_config(sim_cell, **overrides)
    arm = config.arms["arm"].model_copy(update={"rest_pose": REST})
    return config.model_copy(update={"arms": {"arm": arm}})


@pytest.fixture
def connector(sim_cell, make_connector, cell_config):
    return make_connector(rest_config(cell_config, sim_cell))


def raw_motors(names_to_ids: dict[str, int]) -> dict[str, Motor]:
    # The units the cell declares (identity.py): the gripper is 0..100, the body -100..100 (or degrees).
    return {
        name: Motor(i, "sts3215", MotorNormMode.RANGE_0_100 if name == "gripper" else MotorNormMode.RANGE_M100_100)
        for name, i in names_to_ids.items()
    }


def open_bus(client, endpoint: str, motors: dict[str, Motor]) -> str:
    bus = client.create("FeetechMotorsBus", port=endpoint, motors=motors)
    assert client.call(bus, "connect")["ok"]
    return bus


# -- rest and reset through the cell's own bus ---------------------------------------


def test_return_to_rest_moves_every_cell_motor_even_when_the_job_bus_holds_one(
    connector, client_for, sim_cell
) -> None:
    client = client_for(connector.robot_endpoint)
    open_bus(client, connector.robot_endpoint, raw_motors({"gripper": 6}))
    reply = client.request({"op": "return_to_rest"})
    assert reply == {"ok": True}
    assert wait_until(lambda: at_rest(sim_cell), 2.0), sim_cell.arm.positions()
    record = connector.record()
    assert [r.arm for r in record.rests] == ["arm"] and record.rests[0].reached and not record.rest_missed


def test_a_job_bus_that_renames_motors_is_refused_and_rest_still_ends_at_the_cells_rest_pose(
    connector, client_for, sim_cell
) -> None:
    """The job calls servo 5 'shoulder_pan' and servo 1 'wrist_roll' (the cell's names swapped)."""
    client = client_for(connector.robot_endpoint)
    swapped = {"shoulder_pan": 5, "shoulder_lift": 2, "elbow_flex": 3, "wrist_flex": 4, "wrist_roll": 1, "gripper": 6}
    reply = client.request({"op": "create", "class": "FeetechMotorsBus", "args": [],
                            "kwargs": _encoded(port=connector.robot_endpoint, motors=raw_motors(swapped))})
    assert reply["ok"] is False and reply["error_type"] == "NotAllowed", reply  # ids belong to the cell
    assert "shoulder_pan" in reply["error"] or "wrist_roll" in reply["error"]
    assert client.request({"op": "return_to_rest"}) == {"ok": True}
    assert wait_until(lambda: at_rest(sim_cell), 2.0), sim_cell.arm.positions()


def test_reset_after_a_refused_renamed_job_bus_ends_at_the_cells_rest_pose(
    sim_cell, make_connector, cell_config, client_for
) -> None:
    from armnet_connector import LocalOperatorInputs

    connector = make_connector(rest_config(cell_config, sim_cell), inputs=LocalOperatorInputs(auto_confirm_reset=True))
    robot = client_for(connector.robot_endpoint)
    swapped = {"wrist_roll": 1, "shoulder_pan": 5}
    reply = robot.request({"op": "create", "class": "FeetechMotorsBus", "args": [],
                           "kwargs": _encoded(port=connector.robot_endpoint, motors=raw_motors(swapped))})
    assert reply["ok"] is False and reply["error_type"] == "NotAllowed", reply
    assert client_for(connector.operator_endpoint).request({"op": "reset"}) == {"ok": True}
    assert at_rest(sim_cell), sim_cell.arm.positions()


def test_a_rest_that_cannot_reach_a_servo_is_reported_not_ok(connector, client_for, sim_cell) -> None:
    sim_cell.arm.unplug("wrist_roll")
    reply = client_for(connector.robot_endpoint).request({"op": "return_to_rest"})
    assert reply["ok"] is False and reply["error_type"] == "RestNotReached", reply
    assert "did not return to rest" in reply["error"]
    record = connector.record()
    assert record.rest_missed and record.counters["rests_missed"] == 1
    assert record.as_dict()["rests"][0]["reached"] is False


def test_a_rest_whose_position_reads_lose_servo_replies_asks_again_and_reaches_rest(connector, sim_cell) -> None:
    """LeRobot's own num_retry asked again at once and took the late reply as its answer (a loaded CI host).

    The connector's own bus, connected first, so the lost replies are the rest's position reads.
    """
    from armnet_connector.rest import cell_bus, move_to_rest, rest_pose

    arm, ranges = connector.config.arms["arm"], connector.cell.ranges["arm"]
    lost: list[int] = []
    with cell_bus(arm, ranges) as bus:
        sim_cell.arm.drop_replies("elbow_flex", 2)  # the first position read and its first retry
        report = move_to_rest(bus, "arm", rest_pose(arm, ranges), 2000.0, on_lost_reply=lambda: lost.append(1))
    assert report.reached, report.message()
    assert at_rest(sim_cell), sim_cell.arm.positions()
    assert len(lost) >= 2  # both dropped replies counted; a loaded host may lose one more on its own


def test_the_rests_torque_on_asks_again_past_lost_acknowledgements(connector, sim_cell) -> None:
    """CI run 20: a scripted reset's rest failed on "Failed to write 'Torque_Enable' ... after 4 tries":
    LeRobot's num_retry asks at once, and one servo's four acknowledgements were lost on a starved host."""
    from armnet_connector.rest import cell_bus, switch_torque_on

    arm, ranges = connector.config.arms["arm"], connector.cell.ranges["arm"]
    lost: list[int] = []
    with cell_bus(arm, ranges) as bus:
        bus.disable_torque(num_retry=3)
        sim_cell.arm.drop_replies("shoulder_pan", 5)  # more than LeRobot's four quick tries
        try:
            switch_torque_on(bus, list(bus.motors), on_lost_reply=lambda: lost.append(1))
            state = bus.sync_read("Torque_Enable", normalize=False, num_retry=3)
        finally:
            sim_cell.arm.clear_faults()
    assert all(int(v) == 1 for v in state.values()), state
    assert lost  # asked again, and counted


def test_the_cells_own_bus_connects_through_as_many_lost_pings_as_a_jobs_connect(connector, sim_cell) -> None:
    """A scripted reset's rest failed on "Missing motor IDs" after three quick attempts (CI under load)."""
    from armnet_connector.rest import CONNECT_ATTEMPTS, cell_bus
    from armnet_connector.retry import retry_delays

    assert CONNECT_ATTEMPTS == len(retry_delays("connect")) + 1
    arm, ranges = connector.config.arms["arm"], connector.cell.ranges["arm"]
    sim_cell.arm.drop_replies("shoulder_lift", 3)  # every ping of three attempts, as a starved host loses them
    try:
        with cell_bus(arm, ranges) as bus:
            assert bus.is_connected
    finally:
        sim_cell.arm.clear_faults()


def test_a_port_that_does_not_open_is_tried_three_times_not_with_the_handshake_s_patience(
        connector, caplog: pytest.LogCaptureFixture) -> None:
    """A missing device (unplugged, its simulator gone) must not hold every stop up by the handshake's 2.8 s."""
    from armnet_connector.rest import OPEN_ATTEMPTS, cell_bus

    arm = connector.config.arms["arm"].model_copy(update={"port": "/dev/armnet-no-such-port"})
    with caplog.at_level("WARNING", logger="armnet_connector.rest"), pytest.raises(ConnectionError):
        with cell_bus(arm, connector.cell.ranges["arm"], handshake=False):
            pass
    assert OPEN_ATTEMPTS == 3
    assert len([r for r in caplog.records if "retrying" in r.getMessage()]) == OPEN_ATTEMPTS - 1


def test_a_rest_that_ends_outside_its_tolerance_is_reported_not_ok(connector, client_for, sim_cell) -> None:
    """Someone holds the wrist far from its rest pose for the whole move."""
    # Held as an obstacle holds it: the servo pushes, the joint stays. A thread putting the joint
    # back by hand every 10 ms raced the servo's own motion: on a loaded host the thread (and the
    # pipe to the simulator's process) fell behind, the wrist reached its rest, and the move was
    # reported as reaching it.
    sim_cell.arm.move_by_hand("wrist_roll", REST["wrist_roll"] - 800)
    sim_cell.arm.block("wrist_roll")
    try:
        reply = client_for(connector.robot_endpoint).request({"op": "return_to_rest"})
    finally:
        sim_cell.arm.block("wrist_roll", False)
    assert reply["error_type"] == "RestNotReached" and "'wrist_roll'" in reply["error"], reply
    report = connector.record().rests[0]
    assert not report.reached and abs(report.errors["wrist_roll"]) > TOLERANCE
    assert abs(report.errors["elbow_flex"]) <= TOLERANCE  # the rest of the arm got there


# -- bounded time on the bus ----------------------------------------------------------


def test_a_hostile_retry_count_on_a_missing_servo_ends_with_a_clear_error(connector, client_for, sim_cell) -> None:
    client = client_for(connector.robot_endpoint)
    bus = open_bus(client, connector.robot_endpoint, raw_motors({"elbow_flex": 3, "gripper": 6}))
    sim_cell.arm.unplug("gripper")
    started = time.monotonic()
    reply = client.call(bus, "sync_read", "Present_Position", num_retry=10**9)
    took = time.monotonic() - started
    assert reply["ok"] is False and reply["error_type"] == "ConnectionError", reply
    assert took < 20, f"a capped call took {took:.0f} s"
    assert connector.counters.calls_capped == 1
    # A positional count is capped too.
    assert client.call(bus, "disable_torque", None, 10**9)["ok"] is False
    assert connector.counters.calls_capped == 2


def test_a_call_on_a_device_another_call_holds_past_the_wait_gets_device_busy(
    connector, client_for, sim_cell
) -> None:
    client = client_for(connector.robot_endpoint)
    bus = open_bus(client, connector.robot_endpoint, raw_motors({"elbow_flex": 3}))
    lock = connector.cell.locks.get(sim_cell.arm.port)
    held, done = threading.Event(), threading.Event()

    def wedge() -> None:  # a call that does not end, as a driver stuck in the kernel would
        with lock:
            held.set()
            done.wait(30)

    threading.Thread(target=wedge, daemon=True).start()
    assert held.wait(5)
    try:
        reply = client.call(bus, "sync_read", "Present_Position")
    finally:
        done.set()
    assert reply["error_type"] == "DeviceBusy" and "stayed busy" in reply["error"], reply


def test_stop_turns_torque_off_within_the_grace_window_while_a_call_holds_the_device(
    sim_cell, make_connector, cell_config, client_for
) -> None:
    connector = make_connector(cell_config(sim_cell, gracePeriodSeconds=5))
    client = client_for(connector.robot_endpoint)
    bus = open_bus(client, connector.robot_endpoint, raw_motors({"elbow_flex": 3, "gripper": 6}))
    assert client.call(bus, "enable_torque")["ok"]
    assert sim_cell.arm.torque_enabled()["elbow_flex"]
    lock = connector.cell.locks.get(sim_cell.arm.port)
    held, done = threading.Event(), threading.Event()

    def wedge() -> None:
        with lock:
            held.set()
            done.wait(30)

    threading.Thread(target=wedge, daemon=True).start()
    assert held.wait(5)
    try:
        started = time.monotonic()
        connector.stop()
        took = time.monotonic() - started
    finally:
        done.set()
    assert took < 5, f"stop took {took:.1f} s with a wedged call"
    assert not any(sim_cell.arm.torque_enabled().values())
    assert connector.record().torque_off_confirmed == {"arm": True}
    assert connector.counters.stop_lock_timeouts >= 1


def test_stop_after_a_hostile_retry_count_turns_torque_off_within_the_grace_window(
    sim_cell, make_connector, cell_config, client_for
) -> None:
    connector = make_connector(cell_config(sim_cell, gracePeriodSeconds=5))
    client = client_for(connector.robot_endpoint)
    bus = open_bus(client, connector.robot_endpoint, raw_motors({"elbow_flex": 3, "gripper": 6}))
    assert client.call(bus, "enable_torque")["ok"]
    sim_cell.arm.unplug("gripper")
    outcome: list[object] = []

    def hostile_read() -> None:
        try:
            outcome.append(client.call(bus, "sync_read", "Present_Position", num_retry=10**9))
        except Exception as exc:  # noqa: BLE001 — the stop may cut the connection under the call
            outcome.append(exc)

    caller = threading.Thread(target=hostile_read)
    caller.start()
    time.sleep(0.3)  # the call is on the bus
    started = time.monotonic()
    connector.stop()
    took = time.monotonic() - started
    caller.join(30)
    assert not caller.is_alive() and outcome, "the hostile call never ended"
    assert took < 5, f"stop took {took:.1f} s"
    assert not sim_cell.arm.torque_enabled()["elbow_flex"]


def test_a_rest_too_slow_for_the_grace_window_is_cut_short_and_torque_still_goes_off_in_time(
    sim_cell, make_connector, cell_config, client_for
) -> None:
    """The grace window bounds the rest walk: at 40 ticks/s the walk would take half a
    minute; the stop ends it early, reports it missed, and turns torque off within grace."""
    config = rest_config(cell_config, sim_cell, gracePeriodSeconds=5, restOnShutdown=True,
                         restSpeedTicksPerSecond=40)
    connector = make_connector(config)
    client = client_for(connector.robot_endpoint)
    bus = open_bus(client, connector.robot_endpoint, raw_motors({"elbow_flex": 3}))
    assert client.call(bus, "enable_torque")["ok"]
    far = {m: abs(sim_cell.arm.positions()[m] - goal) for m, goal in REST.items()}
    assert max(far.values()) > 400, f"the arm starts too near its rest pose for this test: {far}"
    started = time.monotonic()
    connector.stop()
    took = time.monotonic() - started
    assert took < 5, f"stop took {took:.1f} s, over the 5 s grace window"
    assert not any(sim_cell.arm.torque_enabled().values())
    record = connector.record()
    assert record.torque_off_confirmed == {"arm": True}
    assert [r.reached for r in record.rests] == [False]


# -- one handle's close does not drop the arm under another ---------------------------


def test_closing_one_connections_bus_keeps_torque_for_the_other_until_the_last_closes(
    connector, client_for, sim_cell
) -> None:
    first, second = client_for(connector.robot_endpoint), client_for(connector.robot_endpoint)
    driving = open_bus(first, connector.robot_endpoint, raw_motors({"elbow_flex": 3}))
    watching = open_bus(second, connector.robot_endpoint, raw_motors({"elbow_flex": 3, "gripper": 6}))
    assert first.call(driving, "enable_torque")["ok"]
    assert second.request({"op": "close", "object_id": watching}) == {"ok": True}
    second.close()  # and the whole connection goes away
    time.sleep(0.3)
    assert sim_cell.arm.torque_enabled()["elbow_flex"], "the other connection's arm lost torque"
    present = first.value(driving, "read", "Present_Position", "elbow_flex", normalize=False)
    assert first.call(driving, "write", "Goal_Position", "elbow_flex", present + 20, normalize=False)["ok"]
    assert first.request({"op": "close", "object_id": driving}) == {"ok": True}
    assert not any(sim_cell.arm.torque_enabled().values())
    assert connector.record().torque_off_confirmed == {"arm": True}


def test_the_last_handle_of_a_connection_going_away_turns_torque_off(connector, client_for, sim_cell) -> None:
    client = client_for(connector.robot_endpoint)
    bus = open_bus(client, connector.robot_endpoint, raw_motors({"elbow_flex": 3}))
    assert client.call(bus, "enable_torque")["ok"]
    client.close()
    assert wait_until(lambda: not any(sim_cell.arm.torque_enabled().values()), 5.0)


# -- helpers ------------------------------------------------------------------------------------


def _encoded(**kwargs):
    from armnet_runtime.wire import encode

    return encode(kwargs)


# -- what the host reads ------------------------------------------------------------------------


def test_the_record_tells_the_host_why_the_interlock_holds(make_connector, cell_config) -> None:
    connector = make_connector(cell_config(None))
    fresh = connector.record()
    assert not fresh.interlock_tripped and fresh.trip_reason is None and fresh.rests == ()
    connector.pass_deadline()
    record = connector.record()
    assert record.interlock_tripped and record.trip_reason == "deadline" and record.deadline_passed
    assert "timeout" in (record.trip_message or "")
    as_dict = record.as_dict()
    assert as_dict["tripReason"] == "deadline" and as_dict["counters"]["safety_violations"] == 0
    with pytest.raises(TypeError):
        record.counters["requests"] = 1  # type: ignore[index]  # a snapshot, not the live counters

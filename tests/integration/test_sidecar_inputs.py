"""The cell operator's inputs and the cancel notice reaching a pod job's connector (the path of ``--launcher pod``).

The real connector on the simulated SO-101 serves ``agent.sock`` beside
``observer.sock``, in a directory apart from the job's sockets (in a pod: a
volume of the sidecar only), reached as the agent reaches it on the host:
through the kubelet's long volume path. The agent side is the real inputs
bridge on a real nats-server feeding ``SidecarInputs``; the job side is the
customer SDK's ``Cell`` on the job's operator socket.
"""

from __future__ import annotations

import asyncio
import json
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import nats
import pytest
from armnet_node.inputs_bridge import OperatorInputsBridge
from armnet_node.metrics import AgentMetrics
from armnet_node.sidecar_inputs import SidecarInputs
from armnet_node.sidecar_observer import SidecarObserver
from armnet_node.streams import NatsLink
from armnet_sim import SimulatedCellProcess

from tests.support.sidecar_pod import Pod
from tests.support.sim_connector import request
from tests.support.waiting import wait_for

pytestmark = [pytest.mark.integration, pytest.mark.timeout(120)]

GRACE_S = 30.0


@pytest.fixture
def pod(sim: SimulatedCellProcess) -> Iterator[Pod]:
    pod = Pod(sim, grace_period_seconds=GRACE_S)
    yield pod
    pod.close()


def active_rollout(observer: SidecarObserver) -> Callable[[], int | None]:
    """What ``PodSession.active_rollout`` answers: the sidecar's last event, if a begin."""
    def active() -> int | None:
        events = observer.rollout_events()
        return events[-1].index if events and events[-1].kind == "begin" else None
    return active


def in_background(call: Callable[[], Any]) -> tuple[threading.Thread, list[Any]]:
    """``call`` in a thread (a job blocked in ``reset``); its result or exception lands in the list."""
    result: list[Any] = []

    def run() -> None:
        try:
            result.append(call())
        except Exception as exc:  # noqa: BLE001 - the test asserts on it
            result.append(exc)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread, result


def test_the_pages_confirm_ends_a_pod_jobs_reset(pod: Pod, link: NatsLink, nats_server: str) -> None:
    metrics = AgentMetrics()
    inputs = SidecarInputs(lambda: pod.agent_path, metrics, poll_s=0.1)
    bridge = OperatorInputsBridge(link, inputs, namespace="ns", job_uid="uid-1", cell="cell-in").start()
    assert bridge.wait_active(20)
    inputs.watch(lambda: True)

    async def confirm_on_notice() -> dict[str, Any]:
        nc = await nats.connect(nats_server)
        notices = await nc.subscribe("fms.cell-in.reset.requested")
        await nc.flush()
        job = in_background(pod.job_cell().reset)
        notice = json.loads((await notices.next_msg(timeout=30)).data)
        assert job[1] == [], "the reset returned before anyone confirmed it"
        await nc.publish("fms.cell-in.reset.confirm", json.dumps({"by": "ana", "request": notice["request"]}).encode())
        await nc.flush()
        await nc.close()
        waiting.append(job)
        return dict(notice)

    waiting: list[tuple[threading.Thread, list[Any]]] = []
    try:
        notice = asyncio.run(confirm_on_notice())
        thread, result = waiting[0]
        thread.join(30)
    finally:
        inputs.close()
        bridge.close()
    assert result == [None]  # ctx.cell.reset() returned
    assert notice["job"] == "uid-1"
    # Counted once the connector's reply is back (the job's reset may return first).
    wait_for(lambda: metrics.registry.get_sample_value(
        "armnet_agent_sidecar_inputs_total", {"op": "confirm_reset", "result": "applied"}) == 1,
        what="the applied confirmation counted")


def test_a_confirmation_for_an_earlier_reset_wait_never_confirms_the_waiting_one(pod: Pod) -> None:
    metrics = AgentMetrics()
    inputs = SidecarInputs(lambda: pod.agent_path, metrics)
    first = in_background(pod.job_cell().reset)
    wait_for(lambda: pod.inputs.wait_reset_pending(0), what="the first reset to wait")
    inputs.poll_reset()  # the agent announces wait 1
    assert inputs.pending_reset_wait() == 1  # the bridge repeats its notice while this holds
    assert inputs.confirm_reset() is True
    first[0].join(30)
    inputs.poll_reset()
    assert inputs.pending_reset_wait() is None  # wait 1 ended: the repeats stop
    assert inputs.confirm_reset() is False  # a double click: no reset waits now
    second = in_background(pod.job_cell().reset)
    wait_for(lambda: pod.inputs.wait_reset_pending(0), what="the second reset to wait")
    assert inputs.confirm_reset() is False  # a late click for wait 1, before the agent announced wait 2
    assert pod.inputs.wait_reset_pending(0.3), "the stale confirmation must leave the second reset waiting"
    inputs.poll_reset()
    assert inputs.confirm_reset() is True
    second[0].join(30)
    assert first[1] == [None] and second[1] == [None]
    assert metrics.registry.get_sample_value("armnet_agent_sidecar_inputs_total",
                                             {"op": "confirm_reset", "result": "dropped"}) == 2


def test_the_pages_verdict_reaches_a_pod_jobs_is_complete(pod: Pod, link: NatsLink, nats_server: str) -> None:
    observer = SidecarObserver(lambda: pod.observer_path, AgentMetrics())
    inputs = SidecarInputs(lambda: pod.agent_path, AgentMetrics(), active_rollout=active_rollout(observer))
    bridge = OperatorInputsBridge(link, inputs, namespace="ns", job_uid="uid-1", cell="cell-v",
                                  active_rollout=active_rollout(observer)).start()
    assert bridge.wait_active(20)
    cell = pod.job_cell()
    cell.rollout_begin(index=0, total=2, outcome_controls=True)
    assert cell.is_complete().complete is False

    async def click() -> None:
        nc = await nats.connect(nats_server)
        await nc.publish("fms.cell-v.outcome", json.dumps({"success": True, "by": "ana", "rollout": 0}).encode())
        await nc.flush()
        await nc.close()

    try:
        asyncio.run(click())
        statuses: list[Any] = []
        wait_for(lambda: statuses.append(cell.is_complete()) or statuses[-1].complete, what="the verdict")
    finally:
        bridge.close()
        observer.close()
    assert statuses[-1].success is True


def test_a_verdict_for_a_rollout_that_ended_never_ends_the_next_one(pod: Pod) -> None:
    metrics = AgentMetrics()
    inputs = SidecarInputs(lambda: pod.agent_path, metrics, active_rollout=lambda: 0)  # the agent's view lags
    pod.operator_op("rollout_begin", index=0, total=2, outcome_controls=True)
    pod.operator_op("rollout_end")
    pod.operator_op("rollout_begin", index=1, total=2, outcome_controls=True)
    inputs.report_outcome(False)
    assert pod.job_cell().is_complete().complete is False
    assert metrics.registry.get_sample_value("armnet_agent_sidecar_inputs_total",
                                             {"op": "outcome", "result": "dropped"}) == 1


def test_a_verdict_for_a_rollout_begun_without_outcome_controls_is_dropped(pod: Pod) -> None:
    inputs = SidecarInputs(lambda: pod.agent_path, AgentMetrics(), active_rollout=lambda: 0)
    pod.operator_op("rollout_begin", index=0, total=1, outcome_controls=False)
    inputs.report_outcome(True)
    assert pod.job_cell().is_complete().complete is False


def test_the_cancel_notice_opens_the_grace_window_the_job_sees(pod: Pod) -> None:
    cell = pod.job_cell()
    assert cell.is_shutting_down() is False
    assert SidecarInputs(lambda: pod.agent_path, AgentMetrics()).cancel() is True
    assert cell.is_shutting_down() is True
    status = pod.operator_op("shutdown_status")
    assert 0 < status["grace_remaining_s"] <= GRACE_S
    assert "cancel" in (pod.connector.interlock.trip_info.message or "")


@pytest.mark.parametrize("starts", ["the agent's notice", "the job's first connection"])
def test_a_pods_connector_starts_the_jobs_clock_with_the_job_not_with_itself(sim: SimulatedCellProcess,
                                                                             starts: str) -> None:
    """The sidecar is up before the job's container (whose image may still be pulled): its clock waits for the
    job, so a slow start does not eat the job's timeout; whichever of the two comes first starts it, once."""
    pod = Pod(sim, grace_period_seconds=GRACE_S, timeout_seconds=1.0, clock_starts_with_job=True)
    try:
        time.sleep(2.0)  # twice the timeout, before the job started
        assert not pod.connector.cell.deadline.deadline_passed
        assert not pod.connector.interlock.tripped
        inputs = SidecarInputs(lambda: pod.agent_path, AgentMetrics())
        if starts == "the agent's notice":
            assert inputs.job_started() is True
        else:
            pod.operator_op("shutdown_status")
        wait_for(lambda: pod.connector.cell.deadline.deadline_passed, timeout=10, what="the job's deadline")
        assert "exceeded its timeout of 1 s" in (pod.connector.interlock.trip_info.message or "")
        # A second start (the notice after a connection, an agent that restarted) changes nothing.
        assert request(pod.agent_path, {"op": "job_started"}) == {"ok": True, "applied": True, "already_running": True}
    finally:
        pod.close()


def test_a_cancel_for_a_lost_device_names_the_loss_in_the_interlock(pod: Pod) -> None:
    why = "device lost: arm 'arm''s serial port: /dev/serial/by-id/x does not exist"
    assert SidecarInputs(lambda: pod.agent_path, AgentMetrics()).cancel(why) is True
    assert pod.job_cell().is_shutting_down() is True
    assert pod.connector.interlock.trip_info.message == why


def test_teleop_and_stop_reach_a_pod_jobs_connector(pod: Pod) -> None:
    inputs = SidecarInputs(lambda: pod.agent_path, AgentMetrics())
    inputs.set_teleop_action({"shoulder_pan.pos": 12.5})
    inputs.push_teleop_event("next_episode")
    inputs.request_stop()
    assert pod.inputs.latest_teleop_action() == {"shoulder_pan.pos": 12.5}
    assert pod.inputs.next_teleop_event() == "next_episode"
    assert pod.job_cell().should_stop() is True


@pytest.mark.parametrize("op", [
    {"op": "confirm_reset", "wait": 1}, {"op": "outcome", "success": True, "rollout": None},
    {"op": "cancel"}, {"op": "reset_pending"}, {"op": "stop"}, {"op": "job_started"},
])
def test_the_jobs_sockets_serve_no_agent_input_op(pod: Pod, op: dict[str, Any]) -> None:
    # What the tenant's container can reach (the sockets volume): agent.sock is not in it, and neither of its
    # sockets answers the agent's ops.
    assert sorted(p.name for p in pod.sockets.iterdir() if p.is_socket()) == ["operator.sock", "robot.sock"]
    for name in ("robot.sock", "operator.sock"):
        reply = request(pod.sockets / name, op)
        assert reply["ok"] is False and reply["error_type"] == "UnknownOp"
    assert not pod.connector.cell.deadline.deadline_passed and not pod.inputs.stop_requested()


def test_the_observer_socket_stays_read_only(pod: Pod) -> None:
    for op in ({"op": "confirm_reset", "wait": 0}, {"op": "cancel"}, {"op": "outcome", "success": True}):
        reply = request(pod.observer_path, op)
        assert reply["ok"] is False and reply["error_type"] == "UnknownOp"
    assert not pod.connector.cell.deadline.deadline_passed


@pytest.mark.parametrize("op", [
    {"op": "confirm_reset", "wait": "1"}, {"op": "outcome", "success": "yes"},
    {"op": "teleop_action", "action": {"m": float("nan")}}, {"op": "teleop_event", "event": "launch"},
    {"op": "cancel", "why": 7}, {"op": "cancel", "why": "x" * 501},
])
def test_a_malformed_agent_input_is_refused(pod: Pod, op: dict[str, Any]) -> None:
    reply = request(pod.agent_path, op)
    assert reply["ok"] is False and reply["error_type"] == "ProtocolError"


def test_a_verdict_the_sidecar_drops_is_not_recorded_in_the_history(pod: Pod, link: NatsLink, nats_server: str) -> None:
    recorded: list[tuple[bool, str, int | None]] = []
    metrics = AgentMetrics()
    inputs = SidecarInputs(lambda: pod.agent_path, metrics, active_rollout=lambda: 0)  # the agent's view lags
    bridge = OperatorInputsBridge(link, inputs, namespace="ns", job_uid="uid-1", cell="cell-d",
                                  on_verdict=lambda *verdict: recorded.append(verdict)).start()
    assert bridge.wait_active(20)
    pod.operator_op("rollout_begin", index=0, total=2, outcome_controls=True)
    pod.operator_op("rollout_end")
    pod.operator_op("rollout_begin", index=1, total=2, outcome_controls=True)

    async def click() -> None:
        nc = await nats.connect(nats_server)
        await nc.publish("fms.cell-d.outcome", json.dumps({"success": True, "by": "ana"}).encode())
        await nc.flush()
        await nc.close()

    try:
        asyncio.run(click())
        wait_for(lambda: metrics.registry.get_sample_value(
            "armnet_agent_sidecar_inputs_total", {"op": "outcome", "result": "dropped"}) == 1,
            what="the sidecar to drop the verdict")
    finally:
        bridge.close()
    assert recorded == []
    assert pod.job_cell().is_complete().complete is False

"""Operator inputs published on NATS reach one job's ``LocalOperatorInputs``; hostile ones do not."""

from __future__ import annotations

import asyncio
import json
import threading
import time
import uuid
from collections.abc import Iterator
from datetime import UTC, datetime
from typing import Any

import nats
import pytest
from armnet_connector.cell import RolloutEvent
from armnet_connector.inputs import LocalOperatorInputs
from armnet_core.times import status_time
from armnet_node.inputs_bridge import MAX_INPUT_BYTES, OperatorInputsBridge
from armnet_node.rollout_recorder import RolloutRecorder
from armnet_node.streams import NatsLink, StreamSettings
from armnet_testbed.natsd import NatsServer

from tests.support.waiting import wait_for

pytestmark = [pytest.mark.integration, pytest.mark.timeout(120)]


def send(url: str, *messages: tuple[str, Any]) -> None:
    """Publish each (subject, JSON value or raw bytes) as a cell operator's client would."""

    async def publish() -> None:
        nc = await nats.connect(url)
        for subject, body in messages:
            await nc.publish(subject, body if isinstance(body, bytes) else json.dumps(body).encode())
        await nc.flush()
        await nc.close()

    asyncio.run(publish())


class Job:
    def __init__(self, url: str, bridge: OperatorInputsBridge, inputs: LocalOperatorInputs,
                 namespace: str, uid: str, cell: str) -> None:
        self.url, self.bridge, self.inputs = url, bridge, inputs
        self.teleop = f"teleop.{namespace}.{uid}"
        self.fms = f"fms.{cell}"

    def send(self, *messages: tuple[str, Any]) -> None:
        """Send, then wait until the bridge has handled every one of them."""
        handled = self.bridge.accepted + self.bridge.rejected
        send(self.url, *messages)
        wait_for(lambda: self.bridge.accepted + self.bridge.rejected >= handled + len(messages),
                 what="the bridge to handle the messages")


@pytest.fixture
def job(link: NatsLink, nats_server: str) -> Iterator[Job]:
    namespace, uid, cell = f"t{uuid.uuid4().hex[:8]}", "uid-1", f"cell-{uuid.uuid4().hex[:6]}"
    inputs = LocalOperatorInputs()
    bridge = OperatorInputsBridge(link, inputs, namespace=namespace, job_uid=uid, cell=cell).start()
    assert bridge.wait_active(20)
    yield Job(nats_server, bridge, inputs, namespace, uid, cell)
    bridge.close()


def test_teleop_actions_and_events_reach_the_job(job: Job) -> None:
    job.send((f"{job.teleop}.action", {"action": {"shoulder_pan.pos": 12.5, "gripper.pos": 3}}),
             (f"{job.teleop}.event", {"event": "next_episode"}))
    assert job.inputs.latest_teleop_action() == {"shoulder_pan.pos": 12.5, "gripper.pos": 3.0}
    assert job.inputs.next_teleop_event() == "next_episode"


def test_an_fms_outcome_and_stop_reach_the_job(job: Job) -> None:
    job.send((f"{job.fms}.outcome", {"success": False, "by": "ana"}),
             (f"{job.fms}.stop", {"by": "ana", "reason": "cell door open"}))
    assert job.inputs.take_outcome() is False
    assert job.inputs.stop_requested()


def test_a_confirmation_while_the_reset_waits_confirms_it(job: Job) -> None:
    confirmed: list[bool] = []
    waiter = threading.Thread(target=lambda: confirmed.append(job.inputs.wait_reset_confirmation(20)))
    waiter.start()
    assert job.inputs.wait_reset_pending(10)
    job.send((f"{job.fms}.reset.confirm", {"by": "ana", "request": None}))
    waiter.join(20)
    assert confirmed == [True]


def test_a_confirmation_sent_while_no_reset_waits_does_not_confirm_a_later_reset(job: Job) -> None:
    job.send((f"{job.fms}.reset.confirm", {"by": "ana", "request": None}))
    assert job.bridge.accepted == 1 and job.inputs.ignored_confirmations == 1
    assert job.inputs.wait_reset_confirmation(0.3) is False


@pytest.mark.parametrize("body", [
    b"not json", b"\xff\xfe", b"[1, 2]", b'"a string"', b"{}",
    {"action": {"gripper.pos": "open"}}, {"action": {"gripper.pos": True}}, {"action": [1, 2]},
    {"action": {"gripper.pos": 1}, "extra": 1}, {"action": {f"m{i}": 0 for i in range(200)}},
    {"action": {"x" * 500: 1}}, b'{"action": {"gripper.pos": 1e999}}',
    b'{"action": {"gripper.pos": 1}, "pad": "' + b"x" * MAX_INPUT_BYTES + b'"}',
], ids=lambda body: repr(body)[:40])
def test_a_hostile_teleop_action_is_dropped_and_counted(job: Job, body: Any) -> None:
    job.send((f"{job.teleop}.action", body))
    assert (job.bridge.rejected, job.bridge.accepted) == (1, 0)
    assert job.inputs.latest_teleop_action() is None


@pytest.mark.parametrize(("kind", "body"), [
    ("event", {"event": "launch_missiles"}), ("event", {"event": 1}),
    ("outcome", {"success": "yes", "by": "ana"}), ("outcome", {"success": True}),
    ("outcome", {"success": True, "by": ""}), ("outcome", {"success": True, "by": "ana\u001b[2J"}),
    ("stop", {"by": 7}), ("stop", {"by": "ana", "reason": "x" * 5000}),
    ("reset.confirm", {"by": {"name": "ana"}}), ("reset.confirm", []),
    ("overrule", {"success": False, "by": "ana", "rollout": -1, "startedAt": "2027-01-15T07:58:00.000Z"}),
    ("overrule", {"success": False, "by": "ana", "rollout": 1}),
    ("overrule", {"success": False, "by": "ana", "rollout": 1, "startedAt": "x" * 100}),
])
def test_hostile_fms_and_event_inputs_are_dropped_and_counted(job: Job, kind: str, body: Any) -> None:
    subject = f"{job.teleop}.event" if kind == "event" else f"{job.fms}.{kind}"
    job.send((subject, body))
    assert (job.bridge.rejected, job.bridge.accepted) == (1, 0)
    assert job.inputs.next_teleop_event() is None and job.inputs.take_outcome() is None
    assert not job.inputs.stop_requested() and job.inputs.ignored_confirmations == 0


def test_inputs_reach_the_job_again_after_the_server_restarts(nats_service: NatsServer) -> None:
    link = NatsLink(StreamSettings(url=nats_service.url, reconnect_wait_s=0.2)).start()
    inputs = LocalOperatorInputs()
    bridge = OperatorInputsBridge(link, inputs, namespace="ns", job_uid="uid-r", cell="cell-r").start()
    try:
        assert bridge.wait_active(20)
        nats_service.restart()
        wait_for(lambda: link.connected, what="the link to reconnect")

        def delivered() -> bool:  # the SUB may reach the new server just after the reconnect
            send(nats_service.url, ("teleop.ns.uid-r.event", {"event": "stop_recording"}))
            return inputs.next_teleop_event() == "stop_recording"

        wait_for(delivered, what="a teleop event after the restart")
    finally:
        bridge.close()
        link.stop()


def test_the_cell_operator_is_told_when_a_reset_waits_and_that_confirmation_counts(
    job: Job, nats_server: str
) -> None:
    async def confirm_on_notice() -> dict[str, Any]:
        nc = await nats.connect(nats_server)
        notices = await nc.subscribe(f"{job.fms}.reset.requested")
        await nc.flush()
        waiter.start()
        notice = await notices.next_msg(timeout=20)
        await nc.publish(f"{job.fms}.reset.confirm", json.dumps({"by": "ana", "request": None}).encode())
        await nc.flush()
        await nc.close()
        return dict(json.loads(notice.data))

    confirmed: list[bool] = []
    waiter = threading.Thread(target=lambda: confirmed.append(job.inputs.wait_reset_confirmation(20)))
    wait_for(lambda: job.bridge.link.connected, what="the link to connect")
    notice = asyncio.run(confirm_on_notice())
    waiter.join(20)

    assert confirmed == [True]
    assert notice["job"] == "uid-1" and notice["namespace"] == job.teleop.split(".")[1]


def test_a_confirmation_naming_an_earlier_reset_request_never_confirms_the_waiting_one(job: Job) -> None:
    first: list[bool] = []
    waiter = threading.Thread(target=lambda: first.append(job.inputs.wait_reset_confirmation(0.3)))
    waiter.start()
    waiter.join(10)
    stale = job.bridge._reset_request
    assert first == [False] and stale is not None
    second: list[bool] = []
    waiter = threading.Thread(target=lambda: second.append(job.inputs.wait_reset_confirmation(20)))
    waiter.start()
    wait_for(lambda: job.bridge._reset_request != stale, what="the second reset's announcement")
    job.send((f"{job.fms}.reset.confirm", {"by": "ana", "request": stale}))
    assert job.inputs.wait_reset_pending(0.5), "the stale confirmation must leave the second reset waiting"
    job.send((f"{job.fms}.reset.confirm", {"by": "ana", "request": job.bridge._reset_request}))
    waiter.join(20)
    assert second == [True]


def test_a_lost_reset_notice_is_repeated_with_the_same_request_until_the_reset_is_confirmed(
    link: NatsLink, nats_server: str
) -> None:
    """The page subscribes only after the first notice went out (as after a reconnect): it still gets the prompt."""
    cell = f"cell-{uuid.uuid4().hex[:6]}"
    inputs = LocalOperatorInputs()
    bridge = OperatorInputsBridge(link, inputs, namespace="team-a", job_uid="uid-1", cell=cell,
                                  reannounce_s=0.1).start()
    assert bridge.wait_active(20)
    confirmed: list[bool] = []
    waiter = threading.Thread(target=lambda: confirmed.append(inputs.wait_reset_confirmation(20)))
    try:
        waiter.start()
        wait_for(lambda: bridge._reset_request is not None, what="the first notice")
        first = bridge._reset_request

        async def hear_then_confirm() -> list[dict[str, Any]]:
            nc = await nats.connect(nats_server)
            notices = await nc.subscribe(f"fms.{cell}.reset.requested")
            await nc.flush()
            heard = [json.loads((await notices.next_msg(timeout=10)).data) for _ in range(2)]
            await nc.publish(f"fms.{cell}.reset.confirm",
                             json.dumps({"by": "ana", "request": heard[-1]["request"]}).encode())
            await nc.flush()
            await nc.close()
            return heard

        heard = asyncio.run(hear_then_confirm())
        waiter.join(20)
        sent = bridge.reset_notices_sent
        time.sleep(0.5)  # five repeat periods; one repeat may have been on its way at the click
        after = bridge.reset_notices_sent - sent
    finally:
        bridge.close()
    assert confirmed == [True]
    assert {n["request"] for n in heard} == {first}
    assert heard[1]["elapsed"] > heard[0]["elapsed"] >= 0
    assert after <= 1, "the notice is repeated only while the reset waits"


def test_an_outcome_for_a_rollout_that_is_not_active_never_ends_the_active_one(link: NatsLink, nats_server: str) -> None:
    active: list[int | None] = [2]
    inputs = LocalOperatorInputs()
    cell = f"cell-{uuid.uuid4().hex[:6]}"
    bridge = OperatorInputsBridge(link, inputs, namespace="t-outcome", job_uid="uid-2", cell=cell,
                                  active_rollout=lambda: active[0]).start()
    assert bridge.wait_active(20)
    try:
        job = Job(nats_server, bridge, inputs, "t-outcome", "uid-2", cell)
        job.send((f"fms.{cell}.outcome", {"success": False, "by": "ana", "rollout": 1}))
        assert inputs.take_outcome() is None
        active[0] = None  # between rollouts
        job.send((f"fms.{cell}.outcome", {"success": False, "by": "ana", "rollout": 2}))
        assert inputs.take_outcome() is None
        active[0] = 3
        job.send((f"fms.{cell}.outcome", {"success": True, "by": "ana", "rollout": 3}))
        assert inputs.take_outcome() is True
    finally:
        bridge.close()


def test_a_verdict_for_a_rollout_begun_without_outcome_controls_never_reaches_the_job(
    link: NatsLink, nats_server: str
) -> None:
    events = [RolloutEvent("begin", time.time(), index=1, total=2, outcome_controls=False)]
    recorder = RolloutRecorder(lambda: list(events))
    inputs = LocalOperatorInputs()
    cell = f"cell-{uuid.uuid4().hex[:6]}"
    active: list[int | None] = [1]
    bridge = OperatorInputsBridge(link, inputs, namespace="t-controls", job_uid="uid-3", cell=cell,
                                  active_rollout=lambda: active[0], on_verdict=recorder.verdict,
                                  accepts_verdict=recorder.accepts_verdict).start()
    assert bridge.wait_active(20)
    try:
        job = Job(nats_server, bridge, inputs, "t-controls", "uid-3", cell)
        job.send((f"fms.{cell}.outcome", {"success": True, "by": "ana", "rollout": 1}),
                 (f"fms.{cell}.outcome", {"success": False, "by": "ana"}))
        assert inputs.take_outcome() is None  # the job decides rollout 1 itself
        events.extend([RolloutEvent("end", time.time()),
                       RolloutEvent("begin", time.time(), index=2, total=2, outcome_controls=True)])
        active[0] = 2
        job.send((f"fms.{cell}.outcome", {"success": True, "by": "ana", "rollout": 2}))
        assert inputs.take_outcome() is True
        assert [(e.index, e.outcome.value, e.marked_by) for e in recorder.history] == [
            (1, "unmarked", None), (2, "success", "ana")]
    finally:
        bridge.close()


def test_an_overrule_of_the_monitor_is_recorded_on_the_rollout_it_names_and_never_reaches_the_job(
    link: NatsLink, nats_server: str
) -> None:
    begun = time.time() - 10
    events = [RolloutEvent("begin", begun, index=1, total=2),
              RolloutEvent("verdict", begun + 4, index=1, success=True, score=0.9),
              RolloutEvent("end", begun + 5), RolloutEvent("begin", begun + 6, index=2, total=2)]
    recorder = RolloutRecorder(lambda: list(events))
    inputs = LocalOperatorInputs()
    cell = f"cell-{uuid.uuid4().hex[:6]}"
    bridge = OperatorInputsBridge(link, inputs, namespace="t-overrule", job_uid="uid-4", cell=cell,
                                  active_rollout=lambda: 2, on_verdict=recorder.verdict,
                                  accepts_verdict=recorder.accepts_verdict, on_overrule=recorder.overrule).start()
    assert bridge.wait_active(20)
    started = status_time(datetime.fromtimestamp(begun, UTC))
    try:
        job = Job(nats_server, bridge, inputs, "t-overrule", "uid-4", cell)
        job.send((f"fms.{cell}.overrule", {"success": False, "by": "ana", "rollout": 1, "startedAt": "yesterday"}),
                 (f"fms.{cell}.overrule", {"success": False, "by": "ana", "rollout": 2, "startedAt": started}))
        assert recorder.history[0].outcome.value == "success"  # neither names a rollout the monitor judged
        job.send((f"fms.{cell}.overrule", {"success": False, "by": "ana", "rollout": 1, "startedAt": started}))
        assert [(e.index, e.outcome.value, e.marked_by) for e in recorder.history] == [
            (1, "failure", "ana"), (2, "unmarked", None)]
        assert inputs.take_outcome() is None  # the job, in rollout 2 now, is not told
    finally:
        bridge.close()

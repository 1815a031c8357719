"""The client reads what the agent's own stream library publishes (``armnet_node.streams``).

The other client log tests publish by hand in the documented format; this one
publishes through the agent's ``NatsLink``/``JobStream`` (h-streams, on main),
restarts nats-server while the agent side keeps publishing, and checks that the
client follows every line once, in order, to the terminal status, with the
runtime's timestamps and a Rerun packet intact.
"""

from __future__ import annotations

import threading
import time
import uuid

import pytest
from armnet_client.logstream import CaughtUp, FollowSettings, follow_events
from armnet_client.logwire import LogLine
from armnet_client.viewer import packet_of
from armnet_node import streams
from armnet_runtime.rerun import Entry, Packet, encode_packet
from armnet_testbed.natsd import NatsServer

from tests.integration.client_bed import Publisher, stdout_lines

pytestmark = pytest.mark.integration


def test_every_line_the_agent_publishes_is_followed_once_in_order_across_a_nats_restart(
    nats_service: NatsServer,
) -> None:
    ns, uid = f"ns-{uuid.uuid4().hex[:6]}", uuid.uuid4().hex
    link = streams.NatsLink(streams.StreamSettings(url=nats_service.url)).start()
    job = streams.JobStream(link, ns, uid)
    total = 3000
    job.status("running", {})
    for i in range(1000):
        job.line("stdout", i, f"2026-11-24T10:00:00.{i:06d}Z line {i}")
    packet = Packet(uid, 1, 0, 0, (Entry("action.gripper.pos", scalar=5.0),))
    deadline = time.monotonic() + 30
    while link.pending and time.monotonic() < deadline:  # the link creates the stream, then sends
        time.sleep(0.05)
    assert link.pending == 0, "the agent's link did not deliver its first lines"

    def rest() -> None:
        for i in range(1000, total):
            job.line("stdout", i, f"2026-11-24T10:00:01.{i:06d}Z line {i}")
        job.line("rerun", 0, encode_packet(packet))
        job.status("succeeded", {"exitCode": 0})

    got: list[LogLine] = []
    writer: threading.Thread | None = None
    try:
        for event in follow_events(FollowSettings(nats_service.url, batch=200), ns, uid):
            if isinstance(event, CaughtUp):
                # The link's outbox is ordered: lines published now follow the first 1,000.
                writer = threading.Thread(target=rest, daemon=True)
                writer.start()
                continue
            got.append(event)
            if len([x for x in got if x.kind == "stdout"]) == 1500:
                nats_service.restart()
    finally:
        if writer is not None:
            writer.join(30)
        link.stop()

    stdout = [x for x in got if x.kind == "stdout"]
    assert [x.text for x in stdout] == [f"line {i}" for i in range(total)]
    assert [x.seq for x in stdout] == list(range(total))
    assert stdout[5].time is not None and stdout[5].time.microsecond == 5
    assert [x.text for x in got if x.kind == "status"] == ["status: running", "status: succeeded"]
    assert [packet_of(x) for x in got if x.kind == "rerun"] == [packet]
    assert got[-1].terminal_phase == "succeeded"



def test_a_job_an_older_agent_began_in_single_lines_and_a_newer_one_re_published_in_batches_reads_once(
    nats_server: str,
) -> None:
    ns, uid = f"ns-{uuid.uuid4().hex[:6]}", uuid.uuid4().hex
    Publisher(nats_server, ns, uid).publish(stdout_lines(1, 40))  # one line per message, as before batching
    link = streams.NatsLink(streams.StreamSettings(url=nats_server))  # the upgraded agent re-adopts the job
    job = streams.JobStream(link, ns, uid)
    for i in range(1, 101):  # it re-reads the container log from the start: waiting lines share messages
        job.line("stdout", i, f"line {i}")
    job.status("succeeded", {"exitCode": 0})
    link.start()
    try:
        got = [e for e in follow_events(FollowSettings(nats_server), ns, uid) if isinstance(e, LogLine)]
    finally:
        link.stop()

    assert [(x.seq, x.text) for x in got if x.kind == "stdout"] == [(i, f"line {i}") for i in range(1, 101)]
    assert got[-1].terminal_phase == "succeeded"

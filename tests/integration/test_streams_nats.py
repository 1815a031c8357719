"""Job output to JetStream through ``NatsLink``/``JobStream``, against a real nats-server.

A client replays a job's subject from its first line, in order, each line once;
lines that wait together share messages (``armnet_core.logbatch``), never
across kinds, and a line printed alone leaves alone; a re-published line is
deduplicated; an outage of the server loses nothing and never blocks the
publisher.
"""

from __future__ import annotations

import asyncio
import threading
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import nats
import nats.errors
import pytest
from armnet_client.logstream import FollowSettings, follow_events
from armnet_client.logwire import LogLine, seq_of
from armnet_core.logbatch import LINES_HEADER, split_lines
from armnet_node.streams import (
    MAX_LINE_BYTES,
    JobStream,
    NatsLink,
    StreamSettings,
    line_msg_id,
)
from armnet_testbed.natsd import NatsServer
from armnet_testbed.procs import free_port
from nats.js.api import ConsumerConfig, DeliverPolicy

from tests.support.waiting import wait_for

pytestmark = [pytest.mark.integration, pytest.mark.timeout(120)]


def a_namespace() -> str:
    return f"t{uuid.uuid4().hex[:10]}"


@dataclass(frozen=True)
class Stored:
    """One stored message as a plain subscriber reads it."""

    subject: str
    msg_id: str
    headers: dict[str, str]
    payload: bytes

    @property
    def lines(self) -> list[tuple[int | None, str]]:
        """(line number, text) of each line it carries (one, or a batch's)."""
        return [(seq, data.decode()) for seq, data in split_lines(self.payload, self.headers, seq_of(self.msg_id))]


def replay(url: str, subject: str, expected_lines: int) -> list[Stored]:
    """Every stored message on ``subject``, from the first; reads on a moment past ``expected_lines`` lines."""

    async def read() -> list[Stored]:
        nc = await nats.connect(url)
        try:
            sub = await nc.jetstream().subscribe(
                subject, ordered_consumer=True, config=ConsumerConfig(deliver_policy=DeliverPolicy.ALL)
            )
            got: list[Stored] = []
            lines = 0
            while True:
                try:
                    msg = await sub.next_msg(timeout=5 if lines < expected_lines else 0.5)
                except nats.errors.TimeoutError:
                    return got
                headers = dict(msg.headers or {})
                got.append(Stored(msg.subject, headers.get("Nats-Msg-Id", ""), headers, msg.data))
                lines += len(got[-1].lines)
        finally:
            await nc.close()

    return asyncio.run(read())


def texts(messages: list[Stored]) -> list[str]:
    return [text for message in messages for _, text in message.lines]


def followed(url: str, namespace: str, job_uid: str) -> list[LogLine]:
    """What ``armnet logs`` reads of the job: each line once (by its number), in order."""
    return [e for e in follow_events(FollowSettings(url), namespace, job_uid, follow=False) if isinstance(e, LogLine)]


@pytest.fixture
def link(nats_server: str, tmp_path: Path) -> Iterator[NatsLink]:
    link = NatsLink(StreamSettings(url=nats_server, spool_dir=tmp_path / "spool")).start()
    wait_for(lambda: link.connected, what="the link to connect")
    yield link
    link.stop()


def test_lines_replay_from_the_first_in_order(link: NatsLink, nats_server: str) -> None:
    job = JobStream(link, a_namespace(), "job-1")
    for seq in range(300):
        job.line("stdout", seq, f"line {seq}")
    wait_for(lambda: link.pending == 0, what="every line acknowledged")

    stored = replay(nats_server, job.subject("stdout"), 300)

    assert [line for message in stored for line in message.lines] == [(seq, f"line {seq}") for seq in range(300)]


@pytest.fixture
def waiting_link(nats_server: str) -> Iterator[NatsLink]:
    """A link not started yet: what is published waits, so the first send finds it all (no timing)."""
    link = NatsLink(StreamSettings(url=nats_server, batch_max_lines=1000, batch_max_bytes=16 * 1024))
    yield link
    link.stop()


def test_lines_that_wait_together_share_messages_each_line_once_in_order(
    waiting_link: NatsLink, nats_server: str
) -> None:
    job = JobStream(waiting_link, a_namespace(), "job-batched")
    for seq in range(1, 2501):
        job.line("stdout", seq, f"line {seq}")
    waiting_link.start()
    wait_for(lambda: waiting_link.pending == 0, what="every line acknowledged")

    stored = replay(nats_server, job.subject("stdout"), 2500)

    assert [line for message in stored for line in message.lines] == [(seq, f"line {seq}") for seq in range(1, 2501)]
    assert [(m.headers[LINES_HEADER], m.msg_id) for m in stored] == [
        ("1000", "job-batched:stdout:1-1000"), ("1000", "job-batched:stdout:1001-2000"),
        ("500", "job-batched:stdout:2001-2500")]
    assert waiting_link.published == 2500, "counted in lines"


def test_a_line_longer_than_a_batch_travels_alone_between_its_neighbours(
    waiting_link: NatsLink, nats_server: str
) -> None:
    job = JobStream(waiting_link, a_namespace(), "job-long-line")
    long = "y" * (20 * 1024)  # over batch_max_bytes (16 KiB), under the line limit
    for seq, text in enumerate(["a", "b", long, "c", "d"], start=1):
        job.line("stdout", seq, text)
    waiting_link.start()
    wait_for(lambda: waiting_link.pending == 0, what="every line acknowledged")

    stored = replay(nats_server, job.subject("stdout"), 5)

    assert [m.lines for m in stored] == [[(1, "a"), (2, "b")], [(3, long)], [(4, "c"), (5, "d")]]
    assert LINES_HEADER not in stored[1].headers and stored[1].msg_id == line_msg_id("job-long-line", "stdout", 3)


def test_stdout_and_stderr_keep_their_interleaving(waiting_link: NatsLink, nats_server: str) -> None:
    namespace = a_namespace()
    job = JobStream(waiting_link, namespace, "job-mixed")
    printed = [("stdout", 1, "o1"), ("stdout", 2, "o2"), ("stderr", 1, "e1"), ("stdout", 3, "o3"),
               ("stderr", 2, "e2"), ("stderr", 3, "e3"), ("progress", 1, "half"), ("stdout", 4, "o4")]
    for kind, seq, text in printed:
        job.line(kind, seq, text)
    waiting_link.start()
    wait_for(lambda: waiting_link.pending == 0, what="every line acknowledged")

    stored = replay(nats_server, f"logs.{namespace}.job-mixed.>", len(printed))

    assert [(m.subject.rsplit(".", 1)[-1], seq, text) for m in stored for seq, text in m.lines] == printed
    assert len(stored) == 6, "consecutive lines of one kind share a message; a change of kind starts another"


def test_the_last_lines_of_a_burst_are_sent_with_nothing_after_them(link: NatsLink, nats_server: str) -> None:
    job = JobStream(link, a_namespace(), "job-tail")
    for seq in range(1, 1501):  # a burst that ends mid-batch, then silence (no status, no more lines)
        job.line("stdout", seq, f"line {seq}")
    wait_for(lambda: link.pending == 0, what="every line acknowledged")

    assert texts(replay(nats_server, job.subject("stdout"), 1500)) == [f"line {seq}" for seq in range(1, 1501)]


def test_a_line_printed_alone_leaves_alone_in_the_single_line_format(link: NatsLink, nats_server: str) -> None:
    job = JobStream(link, a_namespace(), "job-quiet")
    job.line("stdout", 1, "hello")
    wait_for(lambda: link.pending == 0, what="the line acknowledged")

    (stored,) = replay(nats_server, job.subject("stdout"), 1)

    assert (stored.payload, stored.msg_id, LINES_HEADER in stored.headers) == (b"hello", "job-quiet:stdout:1", False)


def test_a_line_with_a_newline_in_it_is_never_joined(waiting_link: NatsLink, nats_server: str) -> None:
    job = JobStream(waiting_link, a_namespace(), "job-newline")
    for seq, text in enumerate(["a", "two\nparts", "b"], start=1):
        job.line("stdout", seq, text)
    waiting_link.start()
    wait_for(lambda: waiting_link.pending == 0, what="every line acknowledged")

    stored = replay(nats_server, job.subject("stdout"), 3)

    assert [m.lines for m in stored] == [[(1, "a")], [(2, "two\nparts")], [(3, "b")]]


def test_a_line_published_again_with_the_same_seq_is_read_once(link: NatsLink, nats_server: str) -> None:
    namespace = a_namespace()
    job = JobStream(link, namespace, "job-2")
    for seq in range(5):
        job.line("stderr", seq, f"err {seq}")
    for seq in range(5):  # a re-adopted job re-reads its container log from the start
        job.line("stderr", seq, f"err {seq}")
    job.line("stderr", 5, "err 5")
    wait_for(lambda: link.pending == 0, what="every line acknowledged")

    assert [(x.seq, x.text) for x in followed(nats_server, namespace, "job-2")] == [
        (seq, f"err {seq}") for seq in range(6)]


def test_status_transitions_go_to_the_status_subject_once_per_phase(link: NatsLink, nats_server: str) -> None:
    job = JobStream(link, a_namespace(), "job-3")
    job.status("running", {"startedAt": "2026-01-01T00:00:00Z"})
    job.status("running", {"startedAt": "2026-01-01T00:00:00Z"})
    job.status("succeeded", {"exitCode": 0})
    wait_for(lambda: link.pending == 0, what="the status messages acknowledged")

    statuses = replay(nats_server, job.subject("status"), 2)

    assert [m.msg_id for m in statuses] == ["job-3:status:running", "job-3:status:succeeded"]
    assert b'"phase":"succeeded"' in statuses[1].payload and b'"exitCode":0' in statuses[1].payload


def test_an_outage_of_the_server_loses_no_line_and_duplicates_none(
    nats_service: NatsServer, tmp_path: Path
) -> None:
    settings = StreamSettings(url=nats_service.url, spool_dir=tmp_path / "spool", memory_max_bytes=4096,
                              reconnect_wait_s=0.2, ack_timeout_s=2.0)
    link = NatsLink(settings).start()
    try:
        wait_for(lambda: link.connected, what="the link to connect")
        job = JobStream(link, a_namespace(), "job-out")
        for seq in range(200):
            job.line("stdout", seq, f"before {seq}")
        wait_for(lambda: link.pending == 0, what="the first lines acknowledged")

        assert nats_service._proc is not None
        nats_service._proc.stop()  # the server process goes away mid-stream
        wait_for(lambda: not link.connected, what="the link to notice the outage")
        for seq in range(200, 1200):
            job.line("stdout", seq, f"during {seq}")
        assert link.pending == 1000 and link.spooled > 0, "the outage's lines wait, most of them on disk"
        nats_service.restart()
        wait_for(lambda: link.pending == 0, timeout=60, what="the spooled lines sent after the outage")
    finally:
        link.stop()

    stored = replay(nats_service.url, job.subject("stdout"), 1200)

    expected = [f"before {seq}" for seq in range(200)] + [f"during {seq}" for seq in range(200, 1200)]
    assert texts(stored) == expected, "every line once: a resend repeats the message it resends, and is dropped"
    assert link.dropped == 0
    assert not any((tmp_path / "spool").glob("*.seg")), "a drained spool leaves no file behind"


def test_publish_returns_at_once_while_nats_is_down_and_counts_what_it_cannot_keep() -> None:
    nowhere = f"nats://127.0.0.1:{free_port()}"
    link = NatsLink(StreamSettings(url=nowhere, memory_max_bytes=64 * 1024)).start()
    job = JobStream(link, a_namespace(), "job-down")
    publisher = threading.Thread(
        target=lambda: [job.line("stdout", seq, f"line {seq:06d}") for seq in range(20_000)], daemon=True
    )
    try:
        publisher.start()
        publisher.join(60)
        assert not publisher.is_alive(), "publish blocked while NATS was down"
        assert not link.connected
        assert link.pending + link.dropped == 20_000
        assert link.dropped > 0, "beyond the memory bound (no spool) lines are dropped and counted"
    finally:
        link.stop(timeout_s=0.5)


def test_a_link_without_a_url_does_nothing_and_never_fails() -> None:
    link = NatsLink(StreamSettings(url=None)).start()
    JobStream(link, "ns", "job").line("stdout", 0, "hello")
    link.stop()
    assert (link.connected, link.published, link.dropped, link.pending) == (False, 0, 0, 0)


def test_an_overlong_line_is_cut_with_a_notice_and_a_rerun_packet_is_sent_as_bytes(
    link: NatsLink, nats_server: str
) -> None:
    job = JobStream(link, a_namespace(), "job-long")
    job.line("stdout", 0, "x" * (MAX_LINE_BYTES + 10))
    job.line("rerun", 0, b"\x00\x01packet")
    wait_for(lambda: link.pending == 0, what="the lines acknowledged")

    (text,) = texts(replay(nats_server, job.subject("stdout"), 1))
    (packet,) = replay(nats_server, job.subject("rerun"), 1)

    assert text == "x" * MAX_LINE_BYTES + " ... [armnet: line cut, 10 bytes dropped]"
    assert packet.payload == b"\x00\x01packet"


def test_a_restarted_agent_re_publishing_a_job_from_its_first_line_is_read_once_per_line(
    nats_server: str, tmp_path: Path
) -> None:
    namespace = a_namespace()
    first = NatsLink(StreamSettings(url=nats_server)).start()
    job = JobStream(first, namespace, "job-readopted")
    for seq in range(50):
        job.line("stdout", seq, f"line {seq}")
    wait_for(lambda: first.connected and first.pending == 0, what="the first agent's lines acknowledged")
    first.stop()

    second = NatsLink(StreamSettings(url=nats_server, spool_dir=tmp_path)).start()  # the agent, restarted
    try:
        again = JobStream(second, namespace, "job-readopted")
        for seq in range(80):  # it re-reads the container log from the start; the job went on
            again.line("stdout", seq, f"line {seq}")
        wait_for(lambda: second.connected and second.pending == 0, what="the re-published lines acknowledged")
    finally:
        second.stop()

    # The lines are cut into messages as they waited, so JetStream may keep a re-published
    # line twice; a reader drops a line whose number it has delivered (docs/streams.md).
    assert [(x.seq, x.text) for x in followed(nats_server, namespace, "job-readopted")] == [
        (seq, f"line {seq}") for seq in range(80)]

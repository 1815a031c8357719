"""Job output to JetStream through ``NatsLink``/``JobStream``, against a real nats-server.

A client replays a job's subject from its first line, in order, each line once;
a re-published line is deduplicated; an outage of the server loses nothing and
never blocks the publisher.
"""

from __future__ import annotations

import asyncio
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path

import nats
import nats.errors
import pytest
from armnet_agent.node.streams import (
    MAX_LINE_BYTES,
    JobStream,
    NatsLink,
    StreamSettings,
    line_msg_id,
)
from nats.js.api import ConsumerConfig, DeliverPolicy

from tests.testbed.natsd import NatsServer
from tests.testbed.procs import free_port

pytestmark = [pytest.mark.integration, pytest.mark.timeout(120)]


def a_namespace() -> str:
    return f"t{uuid.uuid4().hex[:10]}"


def wait_for(condition: Callable[[], bool], timeout: float = 30, what: str = "condition") -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.02)


def replay(url: str, subject: str, expected: int) -> list[tuple[str, str]]:
    """(msg id, payload) of every stored message on ``subject``, from the first; reads past ``expected``."""

    async def read() -> list[tuple[str, str]]:
        nc = await nats.connect(url)
        try:
            sub = await nc.jetstream().subscribe(
                subject, ordered_consumer=True, config=ConsumerConfig(deliver_policy=DeliverPolicy.ALL)
            )
            got: list[tuple[str, str]] = []
            while True:
                try:
                    msg = await sub.next_msg(timeout=5 if len(got) < expected else 0.5)
                except nats.errors.TimeoutError:
                    return got
                got.append(((msg.headers or {}).get("Nats-Msg-Id", ""), msg.data.decode()))
        finally:
            await nc.close()

    return asyncio.run(read())


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

    lines = replay(nats_server, job.subject("stdout"), 300)

    assert [text for _, text in lines] == [f"line {seq}" for seq in range(300)]
    assert [msg_id for msg_id, _ in lines] == [line_msg_id("job-1", "stdout", seq) for seq in range(300)]


def test_a_line_published_again_with_the_same_seq_is_stored_once(link: NatsLink, nats_server: str) -> None:
    job = JobStream(link, a_namespace(), "job-2")
    for seq in range(5):
        job.line("stderr", seq, f"err {seq}")
    for seq in range(5):  # a re-adopted job re-reads its container log from the start
        job.line("stderr", seq, f"err {seq}")
    job.line("stderr", 5, "err 5")
    wait_for(lambda: link.pending == 0, what="every line acknowledged")

    lines = replay(nats_server, job.subject("stderr"), 6)

    assert [text for _, text in lines] == [f"err {seq}" for seq in range(6)]


def test_status_transitions_go_to_the_status_subject_once_per_phase(link: NatsLink, nats_server: str) -> None:
    job = JobStream(link, a_namespace(), "job-3")
    job.status("running", {"startedAt": "2026-01-01T00:00:00Z"})
    job.status("running", {"startedAt": "2026-01-01T00:00:00Z"})
    job.status("succeeded", {"exitCode": 0})
    wait_for(lambda: link.pending == 0, what="the status messages acknowledged")

    statuses = replay(nats_server, job.subject("status"), 2)

    assert [msg_id for msg_id, _ in statuses] == ["job-3:status:running", "job-3:status:succeeded"]
    assert '"phase":"succeeded"' in statuses[1][1] and '"exitCode":0' in statuses[1][1]


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

    lines = replay(nats_service.url, job.subject("stdout"), 1200)

    expected = [f"before {seq}" for seq in range(200)] + [f"during {seq}" for seq in range(200, 1200)]
    assert [text for _, text in lines] == expected
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

    (_, text), = replay(nats_server, job.subject("stdout"), 1)
    (_, packet), = replay(nats_server, job.subject("rerun"), 1)

    assert text == "x" * MAX_LINE_BYTES + " ... [armnet: line cut, 10 bytes dropped]"
    assert packet == "\x00\x01packet"


def test_a_restarted_agent_re_publishing_a_job_from_its_first_line_stores_each_line_once(
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

    lines = replay(nats_server, job.subject("stdout"), 80)
    assert [text for _, text in lines] == [f"line {seq}" for seq in range(80)]

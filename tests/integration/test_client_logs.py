"""``armnet_client`` follows a job's log subjects in the real JetStream, as the agent publishes them.

The test publishes exactly what the node agent contract (docs/streams.md)
fixes: subjects ``logs.<namespace>.<jobId>.<kind>`` in the stream
``ARMNET_LOGS`` on ``logs.>``, message ids ``<jobId>:<kind>:<seq>``, and a
publisher that retries a line until JetStream acknowledged it (what the agent's
spool does across an outage), so duplicates are JetStream's to drop.
"""

from __future__ import annotations

import threading
import time
import uuid
from collections.abc import Iterator
from datetime import datetime, timezone
from typing import Any

import pytest
from armnet_client.errors import NatsUnreachable
from armnet_client.logstream import CaughtUp, FollowSettings, follow_events
from armnet_client.logwire import LogLine
from armnet_testbed.natsd import NatsServer

from tests.integration.client_bed import Publisher, stdout_lines, terminal

pytestmark = pytest.mark.integration


def lines_only(events: Iterator[Any]) -> list[LogLine]:
    return [e for e in events if isinstance(e, LogLine)]


@pytest.fixture
def job() -> tuple[str, str]:
    return f"ns-{uuid.uuid4().hex[:6]}", uuid.uuid4().hex


def test_replay_returns_every_stored_line_in_order_and_stops_without_follow(
    nats_server: str, job: tuple[str, str]
) -> None:
    ns, job_id = job
    Publisher(nats_server, ns, job_id).publish(stdout_lines(1, 50))

    got = lines_only(follow_events(FollowSettings(nats_server), ns, job_id, follow=False))

    assert [line.text for line in got] == [f"line {i}" for i in range(1, 51)]
    assert [line.seq for line in got] == list(range(1, 51))
    assert all(line.kind == "stdout" and line.time is not None for line in got)


def test_following_replays_then_delivers_live_lines_until_the_terminal_status(
    nats_server: str, job: tuple[str, str]
) -> None:
    ns, job_id = job
    publisher = Publisher(nats_server, ns, job_id)
    publisher.publish(stdout_lines(1, 10))
    events = follow_events(FollowSettings(nats_server), ns, job_id)
    got: list[str] = []
    for event in events:
        if isinstance(event, CaughtUp):
            publisher.in_thread(stdout_lines(11, 20) + terminal())
            continue
        got.append(event.text)

    assert got == [f"line {i}" for i in range(1, 21)] + ["status: succeeded"]


def test_lines_of_another_job_are_not_delivered(nats_server: str, job: tuple[str, str]) -> None:
    ns, job_id = job
    other = uuid.uuid4().hex
    Publisher(nats_server, ns, other).publish(stdout_lines(1, 5))
    Publisher(nats_server, ns, job_id).publish(stdout_lines(100, 101))

    got = lines_only(follow_events(FollowSettings(nats_server), ns, job_id, follow=False))

    assert [line.text for line in got] == ["line 100", "line 101"]


def test_every_line_arrives_once_and_in_order_across_a_nats_restart_mid_stream(
    nats_service: NatsServer, job: tuple[str, str]
) -> None:
    ns, job_id = job
    total = 4000
    publisher = Publisher(nats_service.url, ns, job_id)
    publisher.publish(stdout_lines(1, 1000))
    settings = FollowSettings(nats_service.url, batch=200)
    thread: threading.Thread | None = None
    got: list[int] = []
    for event in follow_events(settings, ns, job_id):
        if isinstance(event, CaughtUp) and thread is None:
            thread = publisher.in_thread(stdout_lines(1001, total) + terminal())
            continue
        if isinstance(event, LogLine) and event.kind == "stdout":
            got.append(int(event.text.split()[1]))
            if len(got) == 1500:
                nats_service.restart()
    assert thread is not None
    thread.join(timeout=60)

    assert got == list(range(1, total + 1))


def test_an_unreachable_server_is_a_typed_error_that_names_the_url(job: tuple[str, str]) -> None:
    with NatsServer() as server:
        url = server.url
    ns, job_id = job

    with pytest.raises(NatsUnreachable, match="cannot reach NATS at"):
        list(follow_events(FollowSettings(url, connect_timeout_s=0.5), ns, job_id))


def test_a_server_without_the_log_stream_is_a_typed_error_naming_the_stream(
    nats_server: str, job: tuple[str, str]
) -> None:
    ns, job_id = job

    with pytest.raises(NatsUnreachable, match="has no stream ARMNET_NOPE"):
        list(follow_events(FollowSettings(nats_server, stream="ARMNET_NOPE"), ns, job_id))


def test_a_finished_job_without_a_terminal_status_message_ends_after_a_quiet_spell(
    nats_server: str, job: tuple[str, str]
) -> None:
    ns, job_id = job
    publisher = Publisher(nats_server, ns, job_id)
    publisher.publish(stdout_lines(1, 5))
    settings = FollowSettings(nats_server, settle_s=2.0)
    late: threading.Thread | None = None
    got: list[str] = []
    for event in follow_events(settings, ns, job_id, finished=lambda: True):
        if isinstance(event, CaughtUp):
            late = threading.Thread(target=lambda: (time.sleep(0.5), publisher.publish(stdout_lines(6, 8))))
            late.start()
            continue
        got.append(event.text)
    assert late is not None
    late.join()

    assert got == [f"line {i}" for i in range(1, 9)]


def test_since_starts_at_the_first_line_stored_after_that_time(nats_server: str, job: tuple[str, str]) -> None:
    ns, job_id = job
    publisher = Publisher(nats_server, ns, job_id)
    publisher.publish(stdout_lines(1, 3))
    time.sleep(1.0)
    cut = datetime.now(timezone.utc)  # noqa: UP017
    time.sleep(0.2)
    publisher.publish(stdout_lines(4, 5))

    got = lines_only(follow_events(FollowSettings(nats_server), ns, job_id, follow=False, since=cut))

    assert [line.text for line in got] == ["line 4", "line 5"]

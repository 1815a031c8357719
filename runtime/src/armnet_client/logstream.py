"""Following one job's log subjects in JetStream: replay from the first line, then live.

Why not nats-py's ordered consumer: it resets itself after missed heartbeats
and has had bugs doing so, so the reconnect path must be ours and tested against a
really restarted server.
Instead this module keeps the last stream sequence it delivered and, after
anything goes wrong (a reconnect, a consumer the restarted server forgot, a
timeout), makes a fresh ephemeral pull consumer starting at the next sequence.
Messages at or below the last delivered sequence are dropped, so a line is
delivered exactly once and in stream order, across any number of restarts.
A message may carry several lines (``armnet_core.logbatch``); a line whose
number its kind has already delivered is dropped too (a restarted agent
re-publishes a re-adopted job's lines, cut into different messages).

The iterators are synchronous (the CLI and ``Client.logs`` are): they run their
own asyncio loop, one ``fetch`` at a time, in the caller's thread.
:func:`follow_batches` gives what each fetch brought (a few thousand lines at
most) at once, so a printer can write it out in one go; :func:`follow_events`
gives the same one by one.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from datetime import datetime
from typing import Any, Optional

from armnet_core.backoff import BackoffPolicy

from .errors import NatsForbidden, NatsUnreachable
from .logwire import (
    TEXT_KINDS,
    CaughtUp,
    Event,
    LogLine,
    consumer_name,
    decode_message,
    inbox_prefix,
    job_subjects,
)

__all__ = ["DEFAULT_STREAM", "CaughtUp", "Event", "FollowSettings", "follow_batches", "follow_events"]

log = logging.getLogger(__name__)

DEFAULT_STREAM = "ARMNET_LOGS"

#: A fetch or a consumer that failed mid-follow: rebuilt after 0.25 s, doubling, at most 2 s apart. A
#: server back from a restart is followed again within 2 s; one that stays away is asked every 2 s, not
#: four times a second, until ``outage_limit_s`` gives up.
RESUME_BACKOFF = BackoffPolicy(first_s=0.25, max_s=2.0)


@dataclass(frozen=True)
class FollowSettings:
    url: str
    stream: str = DEFAULT_STREAM
    batch: int = 512
    fetch_timeout_s: float = 1.0
    connect_timeout_s: float = 3.0
    outage_limit_s: float = 120.0
    """How long the server may stay unreachable mid-follow before :class:`NatsUnreachable`."""
    settle_s: float = 3.0
    """How long a finished job's stream must stay quiet before a follow without its terminal
    status message ends."""
    yield_lines: int = 2000
    """:func:`follow_batches` hands lines on at least this often: a fetch of many batched
    messages holds far more lines, and keeping them all alive at once costs the garbage
    collector more than the rest of the work."""


class _Session:
    """One connection and the current ephemeral consumer; rebuilt consumers start after ``last``."""

    def __init__(self, settings: FollowSettings, namespace: str, subject: str) -> None:
        self.settings = settings
        self.namespace = namespace
        self.subject = subject
        self.nc: Any = None
        self.sub: Any = None
        self.reconnects = 0
        self.seen_reconnects = 0
        #: Permission violations the server reported (asynchronously, through the error callback).
        self.violations: list[str] = []

    async def connect(self) -> None:
        import nats
        from nats.errors import NoServersError

        async def on_reconnect() -> None:
            self.reconnects += 1

        async def quiet(exc: Exception) -> None:
            if "permissions violation" in str(exc).lower():
                self.violations.append(str(exc))

        try:
            self.nc = await nats.connect(
                self.settings.url, connect_timeout=self.settings.connect_timeout_s,
                max_reconnect_attempts=1, reconnect_time_wait=0.25,
                reconnected_cb=on_reconnect, error_cb=quiet, inbox_prefix=inbox_prefix(self.namespace),
            )
            # nats-py applies the reconnect budget to the first connect too: fail
            # fast on a wrong URL, then keep reconnecting for as long as we follow.
            self.nc.options["max_reconnect_attempts"] = -1
        except (TimeoutError, NoServersError, OSError) as exc:
            raise NatsUnreachable(
                f"cannot reach NATS at {self.settings.url}: {exc}; check --nats-url / ARMNET_NATS_URL"
            ) from exc

    async def subscribe(self, after: int, since: Optional[datetime]) -> None:
        import uuid

        from nats.js.api import AckPolicy, ConsumerConfig, DeliverPolicy

        await self.drop_consumer()
        name = consumer_name(self.namespace, uuid.uuid4().hex)
        if after == 0 and since is not None:
            config = ConsumerConfig(name=name, deliver_policy=DeliverPolicy.BY_START_TIME,
                                    opt_start_time=since, ack_policy=AckPolicy.NONE,
                                    inactive_threshold=30.0)
        else:
            config = ConsumerConfig(name=name, deliver_policy=DeliverPolicy.BY_START_SEQUENCE,
                                    opt_start_seq=after + 1, ack_policy=AckPolicy.NONE,
                                    inactive_threshold=30.0)
        js = self.nc.jetstream()
        self.sub = await js.pull_subscribe(self.subject, stream=self.settings.stream, config=config)
        self.seen_reconnects = self.reconnects

    async def first_subscribe(self, since: Optional[datetime]) -> None:
        """The first consumer; a server without the log stream is as good as no server for logs."""
        from nats.errors import TimeoutError as NatsTimeout
        from nats.js.errors import NotFoundError

        try:
            await self.subscribe(0, since)
        except NotFoundError as exc:
            raise NatsUnreachable(
                f"NATS at {self.settings.url} has no stream {self.settings.stream}: no node agent "
                "has published job logs there (wrong server, or the agents use another --stream)"
            ) from exc
        except (TimeoutError, NatsTimeout) as exc:
            # A refused request gets no reply: the server says why on the error callback.
            await asyncio.sleep(0.1)
            if self.violations:
                raise NatsForbidden(self.namespace, self.violations[0]) from exc
            raise

    async def drop_consumer(self) -> None:
        sub, self.sub = self.sub, None
        if sub is None:
            return
        try:
            await sub.unsubscribe()
        except Exception:  # noqa: BLE001 - the server may have forgotten it; inactivity reaps it anyway
            log.debug("dropping the old consumer failed", exc_info=True)

    async def fetch(self) -> list[Any]:
        from nats.errors import TimeoutError as NatsTimeout

        try:
            return list(await self.sub.fetch(self.settings.batch, timeout=self.settings.fetch_timeout_s))
        except (TimeoutError, NatsTimeout):
            return []

    async def pending(self) -> int:
        info = await self.sub.consumer_info()
        return int(info.num_pending)

    async def close(self) -> None:
        await self.drop_consumer()
        if self.nc is not None:
            try:
                await self.nc.close()
            except Exception:  # noqa: BLE001 - closing a broken connection must not mask the real error
                log.debug("closing the NATS connection failed", exc_info=True)


def follow_events(
    settings: FollowSettings, namespace: str, job_id: str, *, follow: bool = True,
    finished: Optional[Callable[[], bool]] = None, since: Optional[datetime] = None,
    clock: Callable[[], float] = time.monotonic,
) -> Iterator[Event]:
    """Yield the job's lines (and one :class:`CaughtUp`), in stream order, each exactly once.

    ``follow=False`` stops when everything stored has been delivered. With
    ``follow=True`` it stops after the agent's terminal ``status`` message, or
    when ``finished()`` (the job's phase, polled by the caller) says the job is
    over and nothing is pending. Raises :class:`NatsUnreachable` if the server
    cannot be reached at the start or stays away longer than ``outage_limit_s``.
    """
    for batch in follow_batches(settings, namespace, job_id, follow=follow, finished=finished, since=since,
                                clock=clock):
        yield from batch


class _LineNumbers:
    """The highest line number delivered per kind: a line at or below it was delivered already."""

    def __init__(self) -> None:
        self.highest: dict[str, int] = {}

    def new(self, line: LogLine) -> bool:
        if line.seq is None or line.kind not in TEXT_KINDS:
            return True
        if line.seq <= self.highest.get(line.kind, -1):
            return False
        self.highest[line.kind] = line.seq
        return True


def follow_batches(
    settings: FollowSettings, namespace: str, job_id: str, *, follow: bool = True,
    finished: Optional[Callable[[], bool]] = None, since: Optional[datetime] = None,
    clock: Callable[[], float] = time.monotonic,
) -> Iterator[list[Event]]:
    """:func:`follow_events`, a list at a time: what one fetch brought, in lists of about
    ``settings.yield_lines`` (never an empty list)."""
    loop = asyncio.new_event_loop()
    session = _Session(settings, namespace, job_subjects(namespace, job_id))
    last = 0
    numbers = _LineNumbers()
    caught_up = False
    outage_since: Optional[float] = None
    resume = RESUME_BACKOFF.start()
    done_since: Optional[float] = None
    try:
        loop.run_until_complete(session.connect())
        loop.run_until_complete(session.first_subscribe(since))
        while True:
            try:
                if session.sub is None or session.reconnects != session.seen_reconnects:
                    loop.run_until_complete(session.subscribe(last, since))
                msgs = loop.run_until_complete(session.fetch())
                idle_and_done = False
                if not msgs:
                    pending = loop.run_until_complete(session.pending())
                    idle_and_done = pending == 0
                outage_since = None
                resume.succeeded()
            except Exception as exc:  # noqa: BLE001 - any NATS failure: rebuild from the last sequence
                now = clock()
                outage_since = outage_since if outage_since is not None else now
                if now - outage_since > settings.outage_limit_s:
                    raise NatsUnreachable(
                        f"NATS at {settings.url} unreachable for {settings.outage_limit_s:.0f}s "
                        f"while following logs (last line delivered: stream sequence {last}): {exc}"
                    ) from exc
                log.info("log stream interrupted (%s); resuming after stream sequence %d", exc, last)
                session.sub = None
                loop.run_until_complete(asyncio.sleep(resume.failed()))
                continue
            if msgs:
                done_since = None
            batch: list[Event] = []
            ended = False
            for msg in msgs:
                stream_seq, lines = _lines_of(msg)
                if stream_seq <= last:
                    continue
                last = stream_seq
                batch.extend(line for line in lines if numbers.new(line))
                if follow and lines and lines[-1].terminal_phase:
                    ended = True
                    break
                if len(batch) >= settings.yield_lines:
                    yield batch
                    batch = []
            if batch:
                yield batch
            if ended:
                return
            if idle_and_done:
                if not caught_up:
                    caught_up = True
                    yield [CaughtUp()]
                if not follow:
                    return
                if finished is not None and finished():
                    # The phase can be written before the agent's last lines reach the
                    # stream (a spool draining after an outage): end only after a quiet spell.
                    done_since = done_since if done_since is not None else clock()
                    if clock() - done_since >= settings.settle_s:
                        return
                else:
                    done_since = None
    finally:
        loop.run_until_complete(session.close())
        loop.close()


def _lines_of(msg: Any) -> tuple[int, list[LogLine]]:
    """The message's stream sequence and lines; (0, []) for a message that is not JetStream's."""
    try:
        meta = msg.metadata
    except Exception:  # noqa: BLE001 - a non-JetStream message on our inbox: not a log line
        return 0, []
    stream_seq = int(meta.sequence.stream)
    return stream_seq, decode_message(msg.subject, msg.data, headers=msg.headers, stream_seq=stream_seq,
                                      stored_at=meta.timestamp)

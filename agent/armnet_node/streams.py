"""The agent's link to NATS: job output to JetStream, operator inputs from core subjects.

:class:`NatsLink` is one connection per agent process, on its own thread and
asyncio loop, so a job never waits on NATS: :meth:`NatsLink.publish` puts the
message in an :class:`~armnet_node.stream_outbox.Outbox` (memory, then a
bounded disk spool) and returns. A sender task publishes in order with the
message's ``Nats-Msg-Id``, keeps a message until JetStream acknowledged it, and
resends from the first unacknowledged one after an outage; the stream's
duplicate window makes those resends idempotent. Output lines that wait
together are sent together, several to a message (``armnet_core.logbatch``;
the outbox joins them). :class:`JobStream` names one job's subjects and
message ids. Subjects and payloads are described in docs/streams.md.

This module never raises into a caller's publish, and never blocks a job.
"""

from __future__ import annotations

import asyncio
import json
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from armnet_connector.ratelog import RateLimitedLog
from armnet_core.backoff import Backoff, BackoffPolicy
from armnet_core.logbatch import batch_headers
from armnet_core.times import micro_time

from .stream_outbox import BatchLimits, Outbox, OutMessage

log = logging.getLogger(__name__)

LOG_KINDS = ("stdout", "stderr", "progress", "rerun")
TEXT_KINDS = frozenset({"stdout", "stderr", "progress"})
"""Kinds whose lines may share a message (a Rerun packet is binary: always alone)."""
MAX_LINE_BYTES = 64 * 1024
"""A stdout/stderr/progress line longer than this is cut (the tail is dropped, with a notice)."""
MAX_MESSAGE_BYTES = 1000 * 1024
"""Anything larger is dropped at publish: nats-server refuses payloads over 1 MiB by default."""


@dataclass(frozen=True)
class StreamSettings:
    """Where the agent's streams go and how long JetStream keeps them.

    ``url`` None disables NATS: publishing and subscribing are no-ops.
    ``spool_dir`` None keeps unsent messages in memory only (``memory_max_bytes``).
    """

    url: str | None
    stream: str = "ARMNET_LOGS"
    max_age_s: float = 7 * 86400
    max_bytes: int = 1 << 30
    duplicate_window_s: float = 600
    spool_dir: Path | None = None
    spool_max_bytes: int = 256 << 20
    memory_max_bytes: int = 64 << 20
    reconnect_wait_s: float = 1.0
    max_backoff_s: float = 5.0
    ack_timeout_s: float = 5.0
    window: int = 512
    """How many messages are sent before waiting for their JetStream acks."""
    window_bytes: int = 4 << 20
    """A window also ends past this many bytes, so a slow link acks it within ``ack_timeout_s``."""
    batch_max_lines: int = 1000
    """At most this many output lines share one message (1: one line per message, as before batching)."""
    batch_max_bytes: int = 64 * 1024
    """At most this many payload bytes in a message of several lines (a longer line goes alone)."""
    ack_every: int = 64
    """One message in this many (and the last of a window) asks for an ack that vouches for those before it."""


# ------------------------------------------------------------------ subjects


def _token(value: str, what: str) -> str:
    if not value or any(c in value for c in " \t\r\n*>"):
        raise ValueError(f"{what} {value!r} cannot be part of a NATS subject (empty, space, '*' or '>')")
    return value


def log_subject(namespace: str, job_uid: str, kind: str) -> str:
    """``logs.<namespace>.<jobId>.<kind>``; kind is stdout|stderr|progress|rerun|status."""
    return f"logs.{_token(namespace, 'namespace')}.{_token(job_uid, 'job id')}.{kind}"


def teleop_subject(namespace: str, job_uid: str, kind: str) -> str:
    """``teleop.<namespace>.<jobId>.<kind>``; kind is action|event."""
    return f"teleop.{_token(namespace, 'namespace')}.{_token(job_uid, 'job id')}.{kind}"


def fms_subject(cell: str, kind: str) -> str:
    """``fms.<cell>.<kind>``; kind is reset.confirm|outcome|overrule|stop."""
    return f"fms.{_token(cell, 'cell')}.{kind}"


def line_msg_id(job_uid: str, kind: str, seq: int) -> str:
    """The dedup key of one output line: deterministic, so a re-read log re-publishes the same ids."""
    return f"{job_uid}:{kind}:{seq}"


# ------------------------------------------------------------------ the link


class Subscription:
    """A core NATS subscription kept across reconnects; ``close()`` ends it."""

    def __init__(self, link: NatsLink, subject: str, on_message: Callable[[str, bytes], None]) -> None:
        self.subject = subject
        self.on_message = on_message
        self._link = link
        self._active = threading.Event()
        self.closed = False
        self._sub: Any = None

    def wait_active(self, timeout_s: float) -> bool:
        """True once the server has the subscription (messages published after this reach it)."""
        return self._active.wait(timeout_s)

    def close(self) -> None:
        self.closed = True
        self._link._unsubscribe(self)


class InputCounts:
    """Operator inputs and reset notices of every bridge on one link; totals never go down."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.accepted = 0
        self.rejected = 0
        self.reset_notices = 0

    def add(self, *, accepted: int = 0, rejected: int = 0, reset_notices: int = 0) -> None:
        with self._lock:
            self.accepted += accepted
            self.rejected += rejected
            self.reset_notices += reset_notices


class NatsLink:
    """One NATS connection for the agent process; see the module docstring."""

    def __init__(self, settings: StreamSettings) -> None:
        self.settings = settings
        self._outbox = Outbox(settings.memory_max_bytes, settings.spool_dir, settings.spool_max_bytes,
                              BatchLimits(settings.batch_max_lines, settings.batch_max_bytes))
        self._subscriptions: list[Subscription] = []
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._wake: asyncio.Event | None = None
        self._sender_idle = False
        self._stopping = False
        self._stop_deadline = 0.0
        self._nc: Any = None
        self._ready = False
        self._refused_log = RateLimitedLog(log)
        self.published = 0
        self.refused = 0
        #: Every inputs bridge on this link counts here too (the process's totals, for the metrics).
        self.input_counts = InputCounts()

    # counters an operator watches (see stream_metrics)
    @property
    def connected(self) -> bool:
        """Connected and the stream is in place: what is published now goes out now."""
        return self._ready

    @property
    def dropped(self) -> int:
        return self._outbox.dropped + self.refused

    @property
    def spooled(self) -> int:
        return self._outbox.spooled

    @property
    def pending(self) -> int:
        return len(self._outbox)

    @property
    def enabled(self) -> bool:
        return self.settings.url is not None

    # ---------------------------------------------------------- caller side

    def start(self) -> NatsLink:
        if self.enabled and self._thread is None:
            self._thread = threading.Thread(target=self._run, name="armnet-nats", daemon=True)
            self._thread.start()
        return self

    def publish(self, subject: str, payload: bytes, msg_id: str, line_seq: int | None = None) -> None:
        """Queue one message for JetStream; never blocks, never raises (a full queue drops and counts).

        ``line_seq``: the message is output line number ``line_seq`` (no ``\\n`` in it), which
        may share a message with the lines next to it.
        """
        if not self.enabled:
            return
        if self._stopping:
            self._refuse(f"a message on {subject} after the link stopped")
            return
        message = OutMessage(subject, payload, msg_id, line_seq)
        if message.size > MAX_MESSAGE_BYTES:
            self._refuse(f"a {message.size}-byte message on {subject} (over {MAX_MESSAGE_BYTES} bytes)")
            return
        if not self._outbox.put(message):
            self._refused_log.warning("NATS outbox full (memory and spool): dropping messages; "
                                      "%d dropped so far", self._outbox.dropped)
            return
        if self._sender_idle:
            self._kick()

    def notify(self, subject: str, payload: bytes) -> None:
        """A core (not stored) message, best effort: dropped when not connected. For live notices."""
        if not self.enabled or not self._ready:
            return

        async def send() -> None:
            try:
                await self._nc.publish(subject, payload)
            except Exception as exc:  # noqa: BLE001 - a notice is best effort
                log.debug("notice on %s not sent: %s", subject, exc)

        self._call_soon(lambda: asyncio.ensure_future(send()))

    def subscribe(self, subject: str, on_message: Callable[[str, bytes], None]) -> Subscription:
        """A core subscription, (re)established on every connection; ``on_message`` runs on the link's thread."""
        subscription = Subscription(self, subject, on_message)
        if not self.enabled:
            return subscription
        with self._lock:
            self._subscriptions.append(subscription)
        self._call_soon(lambda: asyncio.ensure_future(self._subscribe_now(subscription)))
        return subscription

    def stop(self, timeout_s: float = 5.0) -> None:
        """Send what can be sent within ``timeout_s``, then close; what is left is dropped and counted."""
        if self._thread is None:
            self._stopping = True
            self._outbox.discard_all()
            return
        self._stop_deadline = time.monotonic() + timeout_s
        self._stopping = True
        self._kick()
        self._thread.join(timeout_s + 2.0)
        left = self._outbox.discard_all()
        if left:
            log.warning("NATS link stopped with %d messages unsent; they are dropped", left)
        self._thread = None

    def _refuse(self, what: str, lines: int = 1) -> None:
        self.refused += lines
        self._refused_log.warning("NATS: dropped %s", what)

    def _kick(self) -> None:
        self._call_soon(lambda: self._wake.set() if self._wake is not None else None)

    def _call_soon(self, callback: Callable[[], Any]) -> None:
        loop = self._loop
        if loop is None:
            return
        try:
            loop.call_soon_threadsafe(callback)
        except RuntimeError:
            pass  # the loop has closed: the link is stopping

    def _unsubscribe(self, subscription: Subscription) -> None:
        with self._lock:
            if subscription in self._subscriptions:
                self._subscriptions.remove(subscription)

        async def unsubscribe() -> None:
            if subscription._sub is not None:
                try:
                    await subscription._sub.unsubscribe()
                except Exception:  # noqa: BLE001 - the connection is gone: so is the subscription
                    log.debug("unsubscribe from %s failed", subscription.subject, exc_info=True)

        self._call_soon(lambda: asyncio.ensure_future(unsubscribe()))

    # ---------------------------------------------------------- link thread

    def _run(self) -> None:
        loop = asyncio.new_event_loop()
        try:
            loop.run_until_complete(self._main(loop))
        except Exception:  # noqa: BLE001 - the link must never take the agent down
            log.exception("the NATS link's loop ended with an error; publishing stops")
        finally:
            loop.close()

    async def _main(self, loop: asyncio.AbstractEventLoop) -> None:
        self._wake = asyncio.Event()
        self._loop = loop
        if not await self._connect():
            return
        try:
            await self._send_until_stopped()
        finally:
            self._ready = False
            try:
                await self._nc.close()
            except Exception:  # noqa: BLE001 - closing a broken connection
                log.debug("closing the NATS connection failed", exc_info=True)

    def _backoff(self) -> Backoff:
        """Retries of the connection and of the stream's setup: 0.2 s, doubling, at most ``max_backoff_s``."""
        return BackoffPolicy(first_s=min(0.2, self.settings.max_backoff_s), max_s=self.settings.max_backoff_s).start()

    async def _connect(self) -> bool:
        """Connect, retrying with a bounded backoff until it works or the link stops."""
        import nats

        backoff = self._backoff()
        while not self._stopping:
            try:
                self._nc = await nats.connect(
                    self.settings.url or "", name="armnet-agent", connect_timeout=2,
                    allow_reconnect=True, max_reconnect_attempts=-1,
                    reconnect_time_wait=self.settings.reconnect_wait_s,
                    disconnected_cb=self._on_disconnected, reconnected_cb=self._on_reconnected,
                    error_cb=self._on_error,
                )
            except Exception as exc:  # noqa: BLE001 - any failure to connect is retried
                delay = backoff.failed()
                log.warning("cannot connect to NATS at %s (%s); retrying in %.1f s", self.settings.url, exc, delay)
                await self._sleep(delay)
                continue
            log.info("connected to NATS at %s", self.settings.url)
            with self._lock:
                subscriptions = list(self._subscriptions)
            for subscription in subscriptions:
                await self._subscribe_now(subscription)
            return True
        return False

    async def _sleep(self, seconds: float) -> None:
        """Sleep, waking early when the link is asked to stop or has new work."""
        assert self._wake is not None
        self._wake.clear()
        try:
            await asyncio.wait_for(self._wake.wait(), timeout=seconds)
        except TimeoutError:
            pass

    async def _on_disconnected(self) -> None:
        self._ready = False
        if self._stopping:
            return
        log.warning("disconnected from NATS; publishing waits (memory, then spool)")

    async def _on_reconnected(self) -> None:
        log.info("reconnected to NATS at %s", self._nc.connected_url.netloc if self._nc else "?")
        with self._lock:
            subscriptions = list(self._subscriptions)
        for subscription in subscriptions:
            if subscription._sub is None:
                await self._subscribe_now(subscription)  # made while the connection was down
            # nats-py re-sends every existing subscription on reconnect
        self._kick()

    async def _on_error(self, exc: Exception) -> None:
        log.debug("NATS client error: %s", exc)

    async def _subscribe_now(self, subscription: Subscription) -> None:
        if self._nc is None or subscription.closed or subscription._sub is not None:
            return

        async def deliver(msg: Any) -> None:
            try:
                subscription.on_message(msg.subject, msg.data)
            except Exception:  # noqa: BLE001 - a handler's bug must not end the subscription
                log.exception("handler for %s failed", subscription.subject)

        try:
            subscription._sub = await self._nc.subscribe(subscription.subject, cb=deliver)
            await self._nc.flush(timeout=2)
            subscription._active.set()
        except Exception as exc:  # noqa: BLE001 - retried when the connection comes back
            log.warning("cannot subscribe to %s yet: %s", subscription.subject, exc)

    async def _ensure_stream(self, js: Any) -> bool:
        """Create or update the stream; True once it exists."""
        from nats.js.api import DiscardPolicy, RetentionPolicy, StorageType, StreamConfig
        from nats.js.errors import NotFoundError

        config = StreamConfig(
            name=self.settings.stream, subjects=["logs.>"], retention=RetentionPolicy.LIMITS,
            storage=StorageType.FILE, discard=DiscardPolicy.OLD, max_age=self.settings.max_age_s,
            max_bytes=self.settings.max_bytes, duplicate_window=self.settings.duplicate_window_s,
        )
        try:
            try:
                await js.stream_info(self.settings.stream)
            except NotFoundError:
                await js.add_stream(config)
                log.info("created the JetStream stream %s on logs.>", self.settings.stream)
                return True
            try:
                await js.update_stream(config)
            except Exception as exc:  # noqa: BLE001 - an older config still stores our subjects
                log.warning("JetStream stream %s exists but its limits could not be updated: %s",
                            self.settings.stream, exc)
            return True
        except Exception as exc:  # noqa: BLE001 - JetStream not ready yet (restart), or refused
            log.warning("cannot set up the JetStream stream %s (%s); retrying. If the subjects "
                        "overlap another stream, remove that stream or give this one its subjects.",
                        self.settings.stream, exc)
            return False

    async def _send_until_stopped(self) -> None:
        assert self._wake is not None
        js = self._nc.jetstream()
        backoff = self._backoff()
        while True:
            if self._stopping and (not len(self._outbox) or time.monotonic() >= self._stop_deadline):
                return
            if not self._ready:
                if self._nc.is_connected and await self._ensure_stream(js):
                    self._ready = True
                    backoff.succeeded()
                    continue
                await self._sleep(backoff.failed())
                continue
            batch = self._outbox.peek(self.settings.window, self.settings.window_bytes)
            if not batch:
                self._sender_idle = True
                if not len(self._outbox):
                    await self._sleep(1.0)
                self._sender_idle = False
                continue
            if not await self._send_batch(js, batch):
                self._ready = False  # re-check the connection and the stream before resending

    async def _send_batch(self, js: Any, batch: list[OutMessage]) -> bool:
        """Publish ``batch`` pipelined; remove the acknowledged prefix. False on a transient failure.

        Only every ``ack_every``-th message and the last one ask for a JetStream ack:
        the server stores one connection's messages to a stream in order, so an ack
        for message k vouches for those before it (an ack per message costs the
        Python client several times the throughput). Whatever is not vouched for is
        resent, and the duplicate window drops what was stored already. Counts are
        in lines: a message of several lines counts each.
        """
        from nats.js.errors import APIError, NoStreamResponseError

        every = max(1, self.settings.ack_every)
        acks: list[tuple[int, asyncio.Future[Any]]] = []
        for index, message in enumerate(batch):
            headers = {"Nats-Msg-Id": message.msg_id}
            if message.lines > 1 and message.seq is not None:
                headers.update(batch_headers(message.seq, message.lines))
            try:
                if index == len(batch) - 1 or (index + 1) % every == 0:
                    acks.append((index, await js.publish_async(message.subject, message.payload, headers=headers)))
                else:
                    await self._nc.publish(message.subject, message.payload, headers=headers)
            except Exception as exc:  # noqa: BLE001 - connection lost while sending: resend later
                log.debug("publish failed: %s", exc)
                break
        if acks:
            await asyncio.wait([future for _, future in acks], timeout=self.settings.ack_timeout_s)
        done = 0
        healthy = bool(acks) and acks[-1][0] == len(batch) - 1
        for index, future in acks:
            if not future.done():
                healthy = False
                break
            error = future.exception()
            if isinstance(error, NoStreamResponseError) or (
                isinstance(error, APIError) and (error.code or 0) >= 500
            ):
                healthy = False
                break
            if error is None:
                self.published += sum(m.lines for m in batch[done:index + 1])
            else:
                self.published += sum(m.lines for m in batch[done:index])
                self._refuse(f"a message on {batch[index].subject}: JetStream refused it ({error})",
                             batch[index].lines)
            done = index + 1
        for _, future in acks:
            if not future.done():
                future.cancel()
        self._outbox.remove(done)
        return healthy


# ------------------------------------------------------------------ one job


def _cut(text: str) -> bytes:
    data = text.encode("utf-8", errors="replace")
    if len(data) <= MAX_LINE_BYTES:
        return data
    notice = f" ... [armnet: line cut, {len(data) - MAX_LINE_BYTES} bytes dropped]".encode()
    return data[:MAX_LINE_BYTES].decode("utf-8", errors="ignore").encode() + notice


class JobStream:
    """One job's output subjects: ``logs.<namespace>.<jobId>.<kind>``.

    Lines carry their deterministic sequence number in the msg id, so a job
    re-adopted after an agent restart can re-publish its log from the start and
    JetStream keeps each line once (within the stream's duplicate window).
    """

    def __init__(self, link: NatsLink, namespace: str, job_uid: str) -> None:
        self.link = link
        self.namespace = namespace
        self.job_uid = job_uid
        self._subjects = {kind: log_subject(namespace, job_uid, kind) for kind in (*LOG_KINDS, "status")}

    def subject(self, kind: str) -> str:
        return self._subjects[kind]

    def line(self, kind: str, seq: int, text: str | bytes) -> None:
        """Publish one output line (``bytes`` for a Rerun packet, published as is).

        Text lines may share a message with their neighbours of the same kind
        (docs/streams.md); a line with a ``\\n`` in it always goes alone, so
        readers split batches exactly.
        """
        subject = self._subjects.get(kind)
        if subject is None or kind == "status":
            raise ValueError(f"unknown output kind {kind!r}; one of {', '.join(LOG_KINDS)}")
        payload = text if isinstance(text, bytes) else _cut(text)
        joinable = kind in TEXT_KINDS and b"\n" not in payload
        self.link.publish(subject, payload, line_msg_id(self.job_uid, kind, seq), seq if joinable else None)

    def status(self, phase: str, detail: dict[str, Any]) -> None:
        """Publish a status transition; one message per phase (a repeat of a phase is deduplicated)."""
        body = {"phase": phase, "detail": detail, "at": micro_time(datetime.now(UTC))}
        payload = json.dumps(body, default=str, separators=(",", ":")).encode()
        self.link.publish(self._subjects["status"], payload, f"{self.job_uid}:status:{phase}")


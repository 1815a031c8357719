"""The ordered, bounded queue of messages waiting for JetStream: memory first, then a disk spool.

A job must never wait on NATS, and an outage of minutes must lose nothing, so
every message first lands here. Up to ``memory_max_bytes`` wait in memory;
beyond that (a long outage, or NATS slower than the job) they are appended to
segment files under ``spool_dir`` up to ``spool_max_bytes``; beyond that they
are dropped and counted. Once anything waits on disk, new messages go to disk
too, so the sender always sees them in publish order. The sender peeks at the
oldest messages, and removes them only once JetStream acknowledged them.

Lines that wait together travel together: when the sender peeks, runs of
consecutive output lines of one subject are joined into one message
(``armnet_core.logbatch``), within ``batch_max_lines`` and
``batch_max_bytes``. A burst then costs NATS and its readers one message per
few hundred lines, while a line printed alone still leaves alone, at once.
Once peeked, a message is sealed: a resend after an outage sends the very same
message (same lines, same ``Nats-Msg-Id``), so JetStream's duplicate window
still drops what it stored already. Counts (``len``, ``dropped``) are in lines.

This module does no networking and never raises to a publisher; it is
thread-safe (publishers on any thread, one sender).
"""

from __future__ import annotations

import logging
import os
import struct
import threading
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from armnet_core.logbatch import batch_msg_id, join_lines

log = logging.getLogger(__name__)

SEGMENT_BYTES = 8 << 20
"""A spool segment is closed at this size; a fully sent segment is deleted."""

LOAD_BATCH_BYTES = 1 << 20
"""How much of the spool the sender loads back into memory at a time."""

# subject length, msg id length, payload length, first line's number (-1: none), lines
_HEADER = struct.Struct("<HHIqI")


@dataclass(frozen=True)
class OutMessage:
    """One message for JetStream; ``msg_id`` is its ``Nats-Msg-Id`` (the dedup key).

    ``seq`` is set on an output line that may join its neighbours: the line's
    number. ``lines`` > 1 marks a joined message, ``seq`` then numbering its
    first line. A status message or a Rerun packet has ``seq`` None and always
    travels alone.
    """

    subject: str
    payload: bytes
    msg_id: str
    seq: int | None = None
    lines: int = 1

    @property
    def size(self) -> int:
        return len(self.subject) + len(self.msg_id) + len(self.payload) + _HEADER.size

    def encode(self) -> bytes:
        subject, msg_id = self.subject.encode(), self.msg_id.encode()
        seq = -1 if self.seq is None else self.seq
        return (_HEADER.pack(len(subject), len(msg_id), len(self.payload), seq, self.lines)
                + subject + msg_id + self.payload)


@dataclass(frozen=True)
class BatchLimits:
    """How much one joined message may carry; ``max_lines`` 1 turns joining off."""

    max_lines: int = 1000
    max_bytes: int = 64 * 1024


def _joins(run: list[OutMessage], run_bytes: int, after: OutMessage, limits: BatchLimits) -> bool:
    """Whether ``after`` may join the run: the next line of the same subject, within the limits."""
    last = run[-1]
    return (after.seq is not None and last.seq is not None and after.lines == last.lines == 1
            and after.subject == last.subject and after.seq == last.seq + 1
            and len(run) < limits.max_lines and run_bytes + 1 + len(after.payload) <= limits.max_bytes)


def join_run(run: list[OutMessage]) -> OutMessage:
    """One message carrying every line of ``run`` (consecutive lines of one subject), in order."""
    if len(run) == 1:
        return run[0]
    first, last = run[0], run[-1]
    assert first.seq is not None and last.seq is not None
    return OutMessage(first.subject, join_lines([m.payload for m in run]),
                      batch_msg_id(first.msg_id, last.seq), first.seq, len(run))


def _read_message(stream: BinaryIO) -> OutMessage | None:
    header = stream.read(_HEADER.size)
    if len(header) < _HEADER.size:
        return None
    subject_len, id_len, payload_len, seq, lines = _HEADER.unpack(header)
    body = stream.read(subject_len + id_len + payload_len)
    if len(body) < subject_len + id_len + payload_len:
        return None
    subject = body[:subject_len].decode()
    msg_id = body[subject_len:subject_len + id_len].decode()
    return OutMessage(subject, body[subject_len + id_len:], msg_id, None if seq < 0 else seq, lines)


class _Spool:
    """Segment files in one directory: append at the newest, read from the oldest."""

    def __init__(self, directory: Path, max_bytes: int) -> None:
        self.directory = directory
        self.max_bytes = max_bytes
        self.unread_bytes = 0
        self.unread_messages = 0
        directory.mkdir(parents=True, exist_ok=True)
        self._prefix = f"armnet-nats-{os.getpid()}-"
        self._segments: deque[Path] = deque()
        self._next_index = 0
        self._writer: BinaryIO | None = None
        self._written = 0
        self._reader: BinaryIO | None = None
        self._discard_leftovers()

    def _discard_leftovers(self) -> None:
        # A previous agent process's spool is not resent: a re-adopted job re-reads its
        # container log from the start and re-publishes with the same msg ids.
        for leftover in self.directory.glob("armnet-nats-*.seg"):
            log.info("discarding the NATS spool segment %s of an earlier agent process", leftover)
            leftover.unlink(missing_ok=True)

    def append(self, message: OutMessage) -> bool:
        record = message.encode()
        if self.unread_bytes + len(record) > self.max_bytes:
            return False
        if self._writer is None or self._written >= SEGMENT_BYTES:
            self._open_segment()
        assert self._writer is not None
        self._writer.write(record)
        self._written += len(record)
        self.unread_bytes += len(record)
        self.unread_messages += 1
        return True

    def _open_segment(self) -> None:
        if self._writer is not None:
            self._writer.close()
        path = self.directory / f"{self._prefix}{self._next_index:08d}.seg"
        self._next_index += 1
        self._writer = open(path, "ab")  # noqa: SIM115 - kept open across calls, closed on rotation
        self._written = 0
        self._segments.append(path)

    def load(self, budget: int) -> list[OutMessage]:
        """Up to ``budget`` bytes of the oldest messages, removed from the spool."""
        loaded: list[OutMessage] = []
        used = 0
        while self.unread_messages and used < budget:
            if self._reader is None:
                self._reader = open(self._segments[0], "rb")  # noqa: SIM115 - closed when drained
            if self._writer is not None and self._segments[0] == self._segments[-1]:
                self._writer.flush()  # reading the segment still being written
            message = _read_message(self._reader)
            if message is None:
                if len(self._segments) == 1:
                    break  # the writer's segment, read up to what it has written
                self._drop_oldest_segment()
                continue
            loaded.append(message)
            size = len(message.encode())
            used += size
            self.unread_bytes -= size
            self.unread_messages -= 1
        if not self.unread_messages:
            self._reset()
        return loaded

    def _drop_oldest_segment(self) -> None:
        if self._reader is not None:
            self._reader.close()
            self._reader = None
        self._segments.popleft().unlink(missing_ok=True)

    def _reset(self) -> None:
        for handle in (self._reader, self._writer):
            if handle is not None:
                handle.close()
        self._reader = self._writer = None
        while self._segments:
            self._segments.popleft().unlink(missing_ok=True)
        self.unread_bytes = self.unread_messages = 0

    def close(self) -> None:
        self._reset()


class Outbox:
    """Messages in publish order, bounded; counters say what was spooled and dropped (in lines)."""

    def __init__(self, memory_max_bytes: int, spool_dir: Path | None, spool_max_bytes: int,
                 batch: BatchLimits | None = None) -> None:
        self.memory_max_bytes = memory_max_bytes
        self.batch = batch or BatchLimits()
        self._lock = threading.Lock()
        self._memory: deque[OutMessage] = deque()
        self._memory_bytes = 0
        self._memory_lines = 0
        self._sealed = 0
        """How many of the oldest messages a peek handed out: never joined again, resent as they are."""
        self._spool = _Spool(spool_dir, spool_max_bytes) if spool_dir is not None and spool_max_bytes > 0 else None
        self.spooled = 0
        self.dropped = 0

    def put(self, message: OutMessage) -> bool:
        """Queue ``message``; False when both memory and spool are full (it is dropped and counted)."""
        with self._lock:
            spool_in_use = self._spool is not None and self._spool.unread_messages > 0
            if not spool_in_use and self._memory_bytes + message.size <= self.memory_max_bytes:
                self._memory.append(message)
                self._memory_bytes += message.size
                self._memory_lines += message.lines
                return True
            if self._spool is not None:
                try:
                    if self._spool.append(message):
                        self.spooled += message.lines
                        return True
                except OSError as exc:
                    log.warning("cannot spool a NATS message to %s: %s", self._spool.directory, exc)
            self.dropped += message.lines
            return False

    def peek(self, count: int, max_bytes: int | None = None) -> list[OutMessage]:
        """The ``count`` oldest messages (fewer when fewer wait, or past ``max_bytes``), left in the queue.

        Lines not handed out before are joined first (see the module docstring);
        what this returns is sealed.
        """
        with self._lock:
            if not self._memory and self._spool is not None and self._spool.unread_messages:
                try:
                    for message in self._spool.load(min(LOAD_BATCH_BYTES, self.memory_max_bytes)):
                        self._memory.append(message)
                        self._memory_bytes += message.size
                        self._memory_lines += message.lines
                except OSError as exc:
                    log.warning("cannot read the NATS spool in %s: %s", self._spool.directory, exc)
            if len(self._memory) - self._sealed > 1 and self.batch.max_lines > 1:
                self._join_unsealed(count)
            taken: list[OutMessage] = []
            used = 0
            for message in self._memory:
                if len(taken) >= count or (taken and max_bytes is not None and used + message.size > max_bytes):
                    break
                taken.append(message)
                used += message.size
            self._sealed = max(self._sealed, len(taken))
            return taken

    def _join_unsealed(self, count: int) -> None:
        """Join runs of lines after the sealed messages, up to ``count`` messages in all (lock held)."""
        memory = self._memory
        sealed = [memory.popleft() for _ in range(self._sealed)]
        joined: list[OutMessage] = []
        while memory and len(sealed) + len(joined) < count:
            run = [memory.popleft()]
            run_bytes = len(run[0].payload)
            while memory and _joins(run, run_bytes, memory[0], self.batch):
                run.append(memory.popleft())
                run_bytes += 1 + len(run[-1].payload)
            message = join_run(run)
            if len(run) > 1:
                self._memory_bytes += message.size - sum(m.size for m in run)
            joined.append(message)
        memory.extendleft(reversed(sealed + joined))

    def remove(self, count: int) -> None:
        """Forget the ``count`` oldest messages (acknowledged, or refused for good)."""
        with self._lock:
            for _ in range(min(count, len(self._memory))):
                message = self._memory.popleft()
                self._memory_bytes -= message.size
                self._memory_lines -= message.lines
            self._sealed = max(0, self._sealed - count)

    def __len__(self) -> int:
        """Lines (and other messages) waiting: a joined message counts its lines."""
        with self._lock:
            return self._memory_lines + (self._spool.unread_messages if self._spool is not None else 0)

    def discard_all(self) -> int:
        """Drop everything still waiting (the link stops); returns how many lines, also counted as dropped."""
        with self._lock:
            count = self._memory_lines + (self._spool.unread_messages if self._spool is not None else 0)
            self._memory.clear()
            self._memory_bytes = self._memory_lines = self._sealed = 0
            if self._spool is not None:
                self._spool.close()
            self.dropped += count
            return count

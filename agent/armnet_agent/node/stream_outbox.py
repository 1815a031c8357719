"""The ordered, bounded queue of messages waiting for JetStream: memory first, then a disk spool.

A job must never wait on NATS, and an outage of minutes must lose nothing, so
every message first lands here. Up to ``memory_max_bytes`` wait in memory;
beyond that (a long outage, or NATS slower than the job) they are appended to
segment files under ``spool_dir`` up to ``spool_max_bytes``; beyond that they
are dropped and counted. Once anything waits on disk, new messages go to disk
too, so the sender always sees them in publish order. The sender peeks at the
oldest messages, and removes them only once JetStream acknowledged them.

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

log = logging.getLogger(__name__)

SEGMENT_BYTES = 8 << 20
"""A spool segment is closed at this size; a fully sent segment is deleted."""

LOAD_BATCH_BYTES = 1 << 20
"""How much of the spool the sender loads back into memory at a time."""

_HEADER = struct.Struct("<HHI")  # subject length, msg id length, payload length


@dataclass(frozen=True)
class OutMessage:
    """One message for JetStream; ``msg_id`` is its ``Nats-Msg-Id`` (the dedup key)."""

    subject: str
    payload: bytes
    msg_id: str

    @property
    def size(self) -> int:
        return len(self.subject) + len(self.msg_id) + len(self.payload) + _HEADER.size

    def encode(self) -> bytes:
        subject, msg_id = self.subject.encode(), self.msg_id.encode()
        return _HEADER.pack(len(subject), len(msg_id), len(self.payload)) + subject + msg_id + self.payload


def _read_message(stream: BinaryIO) -> OutMessage | None:
    header = stream.read(_HEADER.size)
    if len(header) < _HEADER.size:
        return None
    subject_len, id_len, payload_len = _HEADER.unpack(header)
    body = stream.read(subject_len + id_len + payload_len)
    if len(body) < subject_len + id_len + payload_len:
        return None
    subject = body[:subject_len].decode()
    msg_id = body[subject_len:subject_len + id_len].decode()
    return OutMessage(subject, body[subject_len + id_len:], msg_id)


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
    """Messages in publish order, bounded; counters say what was spooled and dropped."""

    def __init__(self, memory_max_bytes: int, spool_dir: Path | None, spool_max_bytes: int) -> None:
        self.memory_max_bytes = memory_max_bytes
        self._lock = threading.Lock()
        self._memory: deque[OutMessage] = deque()
        self._memory_bytes = 0
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
                return True
            if self._spool is not None:
                try:
                    if self._spool.append(message):
                        self.spooled += 1
                        return True
                except OSError as exc:
                    log.warning("cannot spool a NATS message to %s: %s", self._spool.directory, exc)
            self.dropped += 1
            return False

    def peek(self, count: int) -> list[OutMessage]:
        """The ``count`` oldest messages (fewer when fewer wait), left in the queue."""
        with self._lock:
            if not self._memory and self._spool is not None and self._spool.unread_messages:
                try:
                    for message in self._spool.load(min(LOAD_BATCH_BYTES, self.memory_max_bytes)):
                        self._memory.append(message)
                        self._memory_bytes += message.size
                except OSError as exc:
                    log.warning("cannot read the NATS spool in %s: %s", self._spool.directory, exc)
            return [self._memory[i] for i in range(min(count, len(self._memory)))]

    def remove(self, count: int) -> None:
        """Forget the ``count`` oldest messages (acknowledged, or refused for good)."""
        with self._lock:
            for _ in range(min(count, len(self._memory))):
                self._memory_bytes -= self._memory.popleft().size

    def __len__(self) -> int:
        with self._lock:
            return len(self._memory) + (self._spool.unread_messages if self._spool is not None else 0)

    def discard_all(self) -> int:
        """Drop everything still waiting (the link stops); returns how many, also counted as dropped."""
        with self._lock:
            count = len(self._memory) + (self._spool.unread_messages if self._spool is not None else 0)
            self._memory.clear()
            self._memory_bytes = 0
            if self._spool is not None:
                self._spool.close()
            self.dropped += count
            return count

"""JSON-lines framing: one newline-terminated line at a time from a blocking socket, bounded.

Every armnet socket speaks one JSON object per line (runtime/PROTOCOL.md): the
connector reads requests from jobs it does not trust, the SDK reads the
connector's replies, the node agent reads the sidecar's. They all cut lines here,
so the rules a hostile peer meets are written once:

- a line longer than its reader's ``limit`` is refused (``LineTooLong``) as soon
  as that many bytes are held without a newline, never buffered on;
- bytes held across many readers can be capped by one shared ``BufferBudget``
  (``BudgetExhausted``), so N connections cannot each hold a line just under the cap;
- a reader given a ``deadline`` waits no longer than that in all, however slowly
  the peer trickles its bytes.

Each caller words these for its own peer (a request refused, a reply missing).
What a line holds, and its JSON text, is ``armnet_runtime.wire``'s business
(``dumps_line``, ``line_codec``): writing a line is ``sock.sendall(dumps_line(obj))``.
The reader uses plain ``recv`` and no buffered file object: on a control loop's
cold caches the file object's Python layers cost measurably (bench/proxy_overhead.py).
"""

from __future__ import annotations

import socket
import threading
import time

RECV_CHUNK = 1 << 16
"""Bytes asked of one ``recv``: a request or a reply usually arrives whole in one."""


class FramingError(Exception):
    """The peer's bytes cannot be framed into lines; the connection must close."""


class LineTooLong(FramingError):
    """More than ``limit`` bytes arrived without a newline."""

    def __init__(self, limit: int) -> None:
        super().__init__(f"a line longer than {limit} bytes")
        self.limit = limit


class BudgetExhausted(FramingError):
    """The shared ``BufferBudget`` cannot hold this reader's unfinished line."""

    def __init__(self) -> None:
        super().__init__("too many unfinished lines are held already")


class BufferBudget:
    """Bytes of unfinished lines, shared by every reader of one server.

    Without a total, N connections each holding a line just under the line cap
    hold N times the cap; with it, the reader that would go over fails.
    """

    def __init__(self, limit: int) -> None:
        self.limit = limit
        self._used = 0
        self._lock = threading.Lock()

    @property
    def used(self) -> int:
        return self._used

    def take(self, size: int) -> bool:
        with self._lock:
            if self._used + size > self.limit:
                return False
            self._used += size
            return True

    def give_back(self, size: int) -> None:
        with self._lock:
            self._used -= size


class LineReader:
    """Newline-framed lines from one blocking socket, read with plain ``recv``.

    ``next()`` returns a line with its newline; at the peer's close, whatever is
    left without one (empty at a clean close): the caller decides whether a
    close is an error. A line over ``limit`` bytes raises ``LineTooLong``, bytes
    the shared ``budget`` cannot hold ``BudgetExhausted``; the socket's own errors
    (``TimeoutError``, ``OSError``) pass through. Each byte is scanned for the
    newline once, so framing stays linear in the line's length. Bytes after a
    line stay for the next ``next()``.
    """

    def __init__(self, sock: socket.socket, limit: int, budget: BufferBudget | None = None) -> None:
        self._sock = sock
        self._limit = limit
        self._budget = budget
        self._buffer = bytearray()
        self._scanned = 0  # bytes of the buffer known to hold no newline
        self._held = 0  # bytes charged to the budget

    @property
    def pending(self) -> int:
        """Bytes received after the last line returned, not yet framed."""
        return len(self._buffer)

    def next(self, deadline: float | None = None) -> bytes:
        """The next line; with ``deadline`` (``time.monotonic()``), ``TimeoutError`` once it passes."""
        if not self._buffer:
            chunk = self._sock.recv(RECV_CHUNK) if deadline is None else self._recv_by(deadline)
            if chunk.find(b"\n") == len(chunk) - 1 and len(chunk) <= self._limit + 1:
                return chunk  # the usual case: one whole line per chunk (or b"" at close)
            self._append(chunk)
        while True:
            end = self._buffer.find(b"\n", self._scanned)
            if end > self._limit:
                raise LineTooLong(self._limit)  # a whole line arrived at once, but longer than the limit
            if end >= 0:
                line = bytes(self._buffer[: end + 1])
                del self._buffer[: end + 1]  # cheap: a bytearray drops its head in place
                self._scanned = 0
                self._release()
                return line
            self._scanned = len(self._buffer)
            if len(self._buffer) > self._limit:
                raise LineTooLong(self._limit)
            chunk = self._sock.recv(RECV_CHUNK) if deadline is None else self._recv_by(deadline)
            if not chunk:
                rest = bytes(self._buffer)
                self.close()
                return rest
            self._append(chunk)

    def _recv_by(self, deadline: float) -> bytes:
        """One ``recv`` that waits only for what is left of ``deadline``."""
        left = deadline - time.monotonic()
        if left <= 0:
            raise TimeoutError("the line did not arrive in time")
        self._sock.settimeout(left)
        return self._sock.recv(RECV_CHUNK)

    def _append(self, chunk: bytes) -> None:
        if self._budget is not None:
            if not self._budget.take(len(chunk)):
                raise BudgetExhausted()
            self._held += len(chunk)
        self._buffer += chunk

    def _release(self) -> None:
        """Give the budget back all but what the buffer still holds."""
        if self._budget is not None and self._held > len(self._buffer):
            self._budget.give_back(self._held - len(self._buffer))
            self._held = len(self._buffer)

    def close(self) -> None:
        """Drop what is buffered and give its bytes back to the budget."""
        self._buffer.clear()
        self._scanned = 0
        self._release()

"""Timestamped stdout/stderr for ``armnet-runtime``.

Every output line of a job gets an ISO-8601 UTC timestamp prefix
(``2026-01-02T03:04:05.123456Z <line>``) so logs replayed from the log stream
keep their timing. Lines are written whole under a lock, so a background writer
(the Rerun streamer, via :meth:`TimestampedStream.write_record`) never splices
into a half-printed customer line and markers stay parseable.
"""

from __future__ import annotations

import sys
import threading
from collections.abc import Callable
from datetime import datetime, timezone
from typing import Any, TextIO

from armnet_runtime.markers import format_timestamp


def _utc_now() -> datetime:
    return datetime.now(timezone.utc)  # noqa: UP017 - the SDK supports Python 3.10


class TimestampedStream:
    """A text stream wrapper that prefixes each line with the time it was started."""

    def __init__(self, inner: TextIO, clock: Callable[[], datetime] = _utc_now) -> None:
        self.inner = inner
        self._clock = clock
        self._lock = threading.RLock()
        self._partial = ""
        self._partial_stamp = ""
        self._mid_line = False  # a partial line was already written out by flush()

    def _stamp(self) -> str:
        return format_timestamp(self._clock()) + " "

    def write(self, text: str) -> int:
        with self._lock:
            if not self._partial and not self._mid_line and text:
                self._partial_stamp = self._stamp()
            pieces = (self._partial + text).split("\n")
            self._partial = pieces.pop()
            for piece in pieces:
                prefix = "" if self._mid_line else (self._partial_stamp or self._stamp())
                self.inner.write(prefix + piece + "\n")
                self._mid_line = False
                self._partial_stamp = self._stamp()
            if not self._partial:
                self._partial_stamp = ""
        return len(text)

    def write_record(self, line: str) -> None:
        """Write ``line`` as one whole timestamped line, never spliced into a pending partial."""
        with self._lock:
            if self._mid_line:
                self.inner.write("\n")
                self._mid_line = False
            self.inner.write(self._stamp() + line + "\n")

    def writelines(self, lines: Any) -> None:
        for line in lines:
            self.write(line)

    def flush(self) -> None:
        with self._lock:
            if self._partial:
                prefix = "" if self._mid_line else (self._partial_stamp or self._stamp())
                self.inner.write(prefix + self._partial)
                self._partial = ""
                self._partial_stamp = ""
                self._mid_line = True
            self.inner.flush()

    def isatty(self) -> bool:
        return self.inner.isatty()

    def fileno(self) -> int:
        return self.inner.fileno()

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)


def emit_line(line: str) -> None:
    """Print ``line`` (a marker) on stdout as one whole line and flush.

    Under ``armnet-runtime`` it never joins a pending partial line (e.g. an
    ``input()`` prompt answered from a pipe), so markers always start a line.
    """
    stream = sys.stdout
    record = getattr(stream, "write_record", None)
    if callable(record):
        record(line)
    else:
        stream.write(line + "\n")
    stream.flush()

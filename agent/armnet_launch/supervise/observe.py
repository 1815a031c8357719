"""Turns a job's output lines into events and the facts the result needs.

Pure: it is fed decoded lines and keeps the last progress message, the
``@main`` return value and traceback (from the marker lines the
``armnet-runtime`` entrypoint prints) and bounded stdout/stderr tails.
Marker syntax is owned by ``armnet_runtime.markers``; this module only maps
its parse onto the events the supervisor's hosts care about.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import Any

from armnet_runtime.markers import cap_traceback, parse_marker_line

from armnet_launch.supervise.tail import DEFAULT_TAIL_CHARS, BoundedTail


class Stream(StrEnum):
    STDOUT = "stdout"
    STDERR = "stderr"


class EventKind(StrEnum):
    LOG = "log"
    PROGRESS = "progress"
    RESULT = "result"
    TRACEBACK = "traceback"
    RERUN = "rerun"


@dataclass(frozen=True)
class OutputEvent:
    """One output line, classified. ``text`` is the line (or progress message)."""

    stream: Stream
    kind: EventKind
    text: str
    value: Any = None


def classify_line(stream: Stream, line: str) -> OutputEvent:
    """Classify one line; only stdout carries markers (stderr is always a log line)."""
    line = line.rstrip("\r\n")
    if stream is not Stream.STDOUT:
        return OutputEvent(stream, EventKind.LOG, line)
    marker = parse_marker_line(line)
    if marker is None:
        return OutputEvent(stream, EventKind.LOG, line)
    kind = EventKind(marker.kind)
    if kind is EventKind.PROGRESS:
        return OutputEvent(stream, kind, str(marker.payload))
    return OutputEvent(stream, kind, line, marker.payload)


class OutputObserver:
    """Accumulates what the result needs from a job's output, line by line."""

    def __init__(self, tail_chars: int = DEFAULT_TAIL_CHARS) -> None:
        self.stdout_tail = BoundedTail(tail_chars)
        self.stderr_tail = BoundedTail(tail_chars)
        self.has_return_value = False
        self.return_value: Any = None
        self.traceback: str | None = None
        self.last_progress: str | None = None

    def feed(self, stream: Stream, line: str) -> OutputEvent:
        event = classify_line(stream, line)
        if event.kind is EventKind.RERUN:
            # Rerun packets are large binary payloads for the viewer, not log text.
            return event
        tail = self.stdout_tail if stream is Stream.STDOUT else self.stderr_tail
        tail.append(line.rstrip("\r\n"))
        if event.kind is EventKind.PROGRESS:
            self.last_progress = event.text
        elif event.kind is EventKind.RESULT:
            self.has_return_value = True
            self.return_value = event.value
        elif event.kind is EventKind.TRACEBACK:
            # The runtime caps it already; cap again since job output is untrusted.
            self.traceback = cap_traceback(str(event.value))
        return event

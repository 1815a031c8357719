"""Printing a job's log lines: timestamped output lines, progress as one live line on a terminal.

On a terminal the progress line is redrawn in place (``\\r`` + clear) under
the output and shows ``[rollout 3/10]`` after a ``rollout_begin``; into a pipe
or file every progress message is an ordinary line, so logs stay greppable.
Lines that arrived together are written together, with one flush: a burst of
output costs one write per NATS fetch, not one per line.
"""

from __future__ import annotations

import re
from collections import deque
from collections.abc import Iterable, Iterator
from datetime import datetime, timedelta
from typing import Optional, TextIO

from ..logwire import CaughtUp, Event, LogLine
from ..render import log_text, progress_text, rollout_of

_CLEAR = "\r\x1b[2K"
_DURATION = re.compile(r"^(\d+)([smhd])$")


def parse_since(text: str, now: datetime) -> datetime:
    """``--since``: a duration (``30s``, ``5m``, ``2h``, ``1d``) or an RFC 3339 time."""
    match = _DURATION.match(text.strip())
    if match:
        unit = {"s": 1, "m": 60, "h": 3600, "d": 86400}[match.group(2)]
        return now - timedelta(seconds=int(match.group(1)) * unit)
    # Not armnet_core.times.parse_time: a person's time without a zone is refused, not read as UTC.
    try:
        moment = datetime.fromisoformat(text.strip().replace("Z", "+00:00"))
    except ValueError:
        raise ValueError(f"--since {text!r}: use a duration like 10m or 2h, or a time like "
                         "2026-11-24T10:00:00Z") from None
    if moment.tzinfo is None:
        raise ValueError(f"--since {text!r}: give the time zone, e.g. a trailing Z for UTC")
    return moment


def tail(events: Iterable[Event], count: Optional[int]) -> Iterator[LogLine]:
    """The last ``count`` output lines stored so far, then everything live (``None``: everything).

    A finished job's terminal status is kept from the backlog too: it says why the job ended.
    """
    for batch in tail_batches(([event] for event in events), count):
        yield from batch


def tail_batches(batches: Iterable[list[Event]], count: Optional[int]) -> Iterator[list[LogLine]]:
    """:func:`tail` over lists of events that arrived together; yields non-empty lists."""
    if count is None:
        for batch in batches:
            lines = [e for e in batch if isinstance(e, LogLine)]
            if lines:
                yield lines
        return
    held: deque[LogLine] = deque(maxlen=max(count, 0) or None)
    end: list[LogLine] = []
    backlog = True
    for batch in batches:
        live: list[LogLine] = []
        for event in batch:
            if isinstance(event, CaughtUp):
                if backlog:
                    live.extend([*(held if count > 0 else []), *end])
                backlog = False
            elif backlog:
                if event.kind in ("stdout", "stderr"):
                    held.append(event)
                elif event.terminal_phase:
                    end[:] = [event]
            else:
                live.append(event)
        if live:
            yield live
    if backlog:
        last = [*(held if count > 0 else []), *end]
        if last:
            yield last


class LogPrinter:
    def __init__(self, out: TextIO, *, live: bool, timestamps: bool = True) -> None:
        self.out = out
        self.live = live
        self.timestamps = timestamps
        self.rollout: Optional[tuple[int, int]] = None
        self._progress: Optional[str] = None

    def show(self, line: LogLine) -> None:
        self.show_all([line])

    def show_all(self, lines: Iterable[LogLine]) -> None:
        """Print ``lines`` in order with one write and one flush."""
        parts: list[str] = []
        for line in lines:
            self._render(line, parts)
        if parts:
            self.out.write("".join(parts))
            self.out.flush()

    def _render(self, line: LogLine, parts: list[str]) -> None:
        if line.kind in ("stdout", "stderr") and self._progress is None:  # the bulk of a log: the short way
            parts.append(log_text(line, timestamps=self.timestamps) + "\n")
            return
        step = rollout_of(line)
        if step is not None:
            self.rollout = step
        if line.kind == "rerun":
            return
        if line.kind == "progress":
            text = progress_text(line, self.rollout) if step is None else (
                f"[rollout {step[0]}/{step[1]}]")
            if self.live:
                self._progress = text
                parts.append(f"{_CLEAR}{text}")
            else:
                self._println(log_text(LogLine("progress", f"[progress] {text}", line.time),
                                       timestamps=self.timestamps), parts)
            return
        self._println(log_text(line, timestamps=self.timestamps), parts)

    def _println(self, text: str, parts: list[str]) -> None:
        if self.live and self._progress is not None:
            parts.append(f"{_CLEAR}{text}\n{self._progress}")
        else:
            parts.append(text + "\n")

    def close(self) -> None:
        if self.live and self._progress is not None:
            self.out.write("\n")
            self.out.flush()
            self._progress = None

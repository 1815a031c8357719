"""How a local run shows a job's output on the terminal, live.

Job stdout goes to our stdout and job stderr to our stderr, line by line;
progress markers become ``[progress] ...`` lines; the result and traceback
markers are not echoed (the final ``JobResult`` shows them) and Rerun packets
are dropped (no viewer here). Messages of ``armnet run`` itself go to stderr,
so with ``--json`` the last stdout line is the ``JobResult`` JSON.
"""

from __future__ import annotations

import sys
import threading
from typing import TextIO

from armnet_launch.supervise.observe import EventKind, OutputEvent, Stream


def progress_line(message: str) -> str:
    return f"[progress] {message}"


class TerminalRenderer:
    """Writes events as they arrive; safe to call from the two reader threads."""

    def __init__(self, out: TextIO | None = None, err: TextIO | None = None) -> None:
        self._out = out or sys.stdout
        self._err = err or sys.stderr
        self._lock = threading.Lock()

    def __call__(self, event: OutputEvent) -> None:
        if event.kind in (EventKind.RESULT, EventKind.TRACEBACK, EventKind.RERUN):
            return
        text = progress_line(event.text) if event.kind is EventKind.PROGRESS else event.text
        target = self._out if event.stream is Stream.STDOUT else self._err
        with self._lock:
            target.write(text + "\n")
            target.flush()

    def note(self, message: str) -> None:
        """A message from ``armnet run`` itself (never on stdout)."""
        with self._lock:
            self._err.write(f"armnet run: {message}\n")
            self._err.flush()

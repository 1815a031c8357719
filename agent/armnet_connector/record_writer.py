"""The thread each part of the cell's record of a job writes on, and how the connector's stop ends it.

Why one shape for the three writers (``servo_trace``, ``camera_video``, ``rollout_frames``): the
connector's stop has one budget within the job's grace window (a pod's record line is printed
after it, before the kubelet's kill). The stop first asks every writer to finish (``close``: no
new work after its drain time), so all drain at once, then waits for them together until the
budget's end (``join``). A writer still busy then finishes on its daemon thread; the stop never
waits past its budget for a file.
"""

from __future__ import annotations

import abc
import threading
import time
from collections.abc import Iterable


class RecordWriter(abc.ABC):
    """A daemon thread running ``_run``; ``closing`` is set by ``close``, ``drain_until`` is when to give up."""

    thread_name = "armnet-record"
    #: How long ``stop()`` without an argument lets the writer finish.
    default_drain_s = 3.0

    def __init__(self) -> None:
        self.closing = threading.Event()
        #: ``time.monotonic()`` past which the writer starts no new work (set by ``close``).
        self.drain_until = 0.0
        self._thread: threading.Thread | None = None

    def start(self) -> RecordWriter:
        self._thread = threading.Thread(target=self._run, name=self.thread_name, daemon=True)
        self._thread.start()
        return self

    @abc.abstractmethod
    def _run(self) -> None:
        """The writer's loop: until ``closing``, then what is pending within the drain time."""

    def draining(self) -> bool:
        """The stop asked to finish and the drain's time is up: start nothing more."""
        return self.closing.is_set() and time.monotonic() >= self.drain_until

    def close(self, drain_s: float) -> None:
        """Finish what is pending for at most ``drain_s`` more, then end (returns at once)."""
        self.drain_until = time.monotonic() + max(drain_s, 0.0)
        self.closing.set()

    def join(self, timeout_s: float) -> bool:
        """Wait for the thread at most ``timeout_s``; True once it has ended (or never started)."""
        thread = self._thread
        if thread is None:
            return True
        thread.join(max(timeout_s, 0.0))
        if thread.is_alive():
            return False  # it counts what it leaves when it ends
        self._thread = None
        return True

    def stop(self, drain_s: float | None = None) -> bool:
        """``close`` then ``join``: True once the writer has ended within ``drain_s`` (None: its default)."""
        drain = self.default_drain_s if drain_s is None else drain_s
        self.close(drain)
        return self.join(drain)


def stop_writers(writers: Iterable[tuple[RecordWriter | None, float]], until: float) -> None:
    """Close every writer with its drain time (none past ``until``, a ``time.monotonic()``), then wait for all."""
    started = [(writer, drain_s) for writer, drain_s in writers if writer is not None]
    now = time.monotonic()
    for writer, drain_s in started:
        writer.close(min(drain_s, until - now))
    for writer, _drain in started:
        writer.join(until - time.monotonic())

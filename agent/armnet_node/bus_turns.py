"""Probe and launch take turns on a cell's bus.

The heartbeat probes the servos over the cell's serial port; a job's connector
opens the same port. If a probe overlaps a job's start, the servos answer
neither reliably, and the failed probe (``ServoNotResponding``) would be kept as
the cell's hardware facts for the whole job: the cell shows Faulted while its
job runs. So the hardware read and the launch step (until the worker has its
runner, after which the probe sees the bus held and reads nothing) exclude each
other, and a probe is only kept when no launch began since it started.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TypeVar

T = TypeVar("T")


class BusTurns:
    """One lock per cell: a hardware probe or a launch step, never both at once."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._launches = 0

    @contextmanager
    def launching(self) -> Iterator[None]:
        """Hold the bus for the launch step; a probe under way finishes first."""
        with self._lock:
            self._launches += 1
            yield

    def probe(self, read: Callable[[], T], bus_held: Callable[[], bool]) -> T | None:
        """``read()`` while no launch step runs; ``None`` when a job holds the bus.

        ``bus_held`` is asked inside the turn, so a launch that finished while
        the probe waited is seen. A result read while a launch began (which the
        lock rules out, and this check keeps ruled out) is discarded.
        """
        with self._lock:
            if bus_held():
                return None
            began = self._launches
            result = read()
            return result if self._launches == began else None

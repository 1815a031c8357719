"""The cell's interlock: once tripped, motion is refused until the job ends.

This module owns the latch and its reason. It never decides *when* to trip
(safety, deadline and reset do) and never talks to hardware.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum

log = logging.getLogger(__name__)


class TripReason(StrEnum):
    SAFETY = "safety"
    DEADLINE = "deadline"
    RESET_TIMEOUT = "reset_timeout"
    SHUTDOWN = "shutdown"
    # A connector re-created for a job adopted after an agent restart: the previous
    # connector's view of the arm (positions, pending reset) is lost, so motion stays refused.
    AGENT_RESTARTED = "agent_restarted"


@dataclass(frozen=True)
class Trip:
    reason: TripReason
    message: str


class Interlock:
    """A latch: the first trip is kept (it explains the rest); it never clears within a job."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._trip: Trip | None = None
        #: Told of the trip, once, after it latched (the cell's servo trace); must not raise.
        self.on_trip: Callable[[Trip], None] | None = None

    @property
    def tripped(self) -> bool:
        return self._trip is not None

    @property
    def trip_info(self) -> Trip | None:
        return self._trip

    def trip(self, reason: TripReason, message: str) -> bool:
        """Trip the interlock; True if this call tripped it (False if it already held)."""
        trip = Trip(reason, message)
        with self._lock:
            if self._trip is not None:
                return False
            self._trip = trip
        # Tripping on shutdown is teardown, not news; every other trip is.
        level = logging.INFO if reason is TripReason.SHUTDOWN else logging.WARNING
        log.log(level, "interlock tripped (%s): %s", reason, message)
        if self.on_trip is not None:
            self.on_trip(trip)
        return True

    def refusal(self) -> tuple[str, str] | None:
        """(error_type, message) for a motion request, or ``None`` when motion is allowed."""
        trip = self._trip
        if trip is None:
            return None
        if trip.reason is TripReason.DEADLINE:
            return (
                "ShuttingDown",
                f"the job is in its grace window ({trip.message}): robot motion is refused. "
                "Finish up (save your data) and return; ctx.is_shutting_down() is True.",
            )
        return (
            "InterlockTripped",
            f"the cell's interlock holds ({trip.reason}: {trip.message}); motion is refused "
            "until the job ends. Reads and disabling torque still work.",
        )

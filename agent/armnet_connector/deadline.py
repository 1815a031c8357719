"""The job's deadline: at ``timeoutSeconds`` trip the interlock and open the grace window.

This module owns the clock side of a job's end. It never kills anything: when
the grace window closes it calls the host's ``on_grace_expired`` callback
(``armnet run`` kills its subprocess; the agent kills the pod's container).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

from .interlock import Interlock, TripReason

log = logging.getLogger(__name__)

CANCELLED_MESSAGE = "the job was cancelled"


def timeout_message(timeout_s: float | None) -> str:
    """What the interlock's trip says at the deadline: the job's timeout as configured (``2 s``)."""
    if timeout_s is None:
        return "the job exceeded its timeout"
    return f"the job exceeded its timeout of {timeout_s:g} s"


class Deadline:
    """Timer thread: deadline → interlock + grace window → ``on_grace_expired``."""

    def __init__(
        self,
        timeout_s: float | None,
        grace_s: float,
        interlock: Interlock,
        on_grace_expired: Callable[[], None] | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.timeout_s = timeout_s
        self.grace_s = grace_s
        self._interlock = interlock
        self._on_grace_expired = on_grace_expired
        self._clock = clock
        self._started_at: float | None = None
        self._start_lock = threading.Lock()
        self._passed_at: float | None = None
        self._expired = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        """Start the job's clock; once only (a later call, e.g. a second notice of the job's start, is ignored)."""
        with self._start_lock:
            if self._started_at is not None:
                return
            self._started_at = self._clock()
        if self.timeout_s is None:
            return
        self._thread = threading.Thread(target=self._run, name="armnet-deadline", daemon=True)
        self._thread.start()

    @property
    def started(self) -> bool:
        return self._started_at is not None

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2)

    def _run(self) -> None:
        assert self.timeout_s is not None
        if self._stop.wait(self.timeout_s):
            return
        self.pass_deadline()
        if self._stop.wait(self.grace_s):
            return
        self._expired.set()
        log.warning("grace window of %g s closed: the job process must end now", self.grace_s)
        if self._on_grace_expired is not None:
            try:
                self._on_grace_expired()
            except Exception:  # the host's callback must not kill the timer thread silently
                log.exception("on_grace_expired callback failed")

    def pass_deadline(self, timeout_s: float | None = None) -> None:
        """Enter the grace window now because the job ran out of time (the timer does this).

        ``timeout_s``: the job's timeout when the host's clock ran it out (``armnet run`` and
        the agent's container jobs give this connector no timeout: one clock only).
        """
        self._enter_grace(timeout_message(timeout_s if timeout_s is not None else self.timeout_s))

    def cancel(self, why: str = CANCELLED_MESSAGE) -> None:
        """Enter the grace window now because the job was stopped (``why``: cancelled, its device lost).

        The same window as a timeout (the job gets ``grace_s`` to save its data),
        but the interlock's reason names the stop: a job without a timeout was
        otherwise told it "exceeded its timeout of None s".
        """
        self._enter_grace(why)

    def _enter_grace(self, why: str) -> None:
        if self._passed_at is not None:
            return
        self._passed_at = self._clock()
        self._interlock.trip(TripReason.DEADLINE, why)
        log.warning("%s: interlock tripped, grace window of %g s open", why, self.grace_s)

    @property
    def deadline_passed(self) -> bool:
        """Whether the job ran past its timeout: its final status is ``timeout``."""
        return self._passed_at is not None

    @property
    def grace_expired(self) -> bool:
        return self._expired.is_set()

    def grace_remaining_s(self) -> float | None:
        if self._passed_at is None:
            return None
        return max(0.0, self.grace_s - (self._clock() - self._passed_at))

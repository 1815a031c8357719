"""Log lines that a hostile or broken peer can cause, at most one per interval.

A job can make the connector fail the same way thousands of times a second
(connections at the descriptor limit, malformed requests). Each failure is
still counted; the log shows the first one and then, once per interval, how
many were suppressed, so a cell's log stays readable and its disk stays free.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any


class RateLimitedLog:
    def __init__(self, logger: logging.Logger, interval_s: float = 10.0) -> None:
        self._logger = logger
        self._interval_s = interval_s
        self._lock = threading.Lock()
        self._last_emitted = float("-inf")
        self._suppressed = 0

    def warning(self, message: str, *args: Any) -> bool:
        """Log ``message`` unless one was logged within the interval; True when logged."""
        now = time.monotonic()
        with self._lock:
            if now - self._last_emitted < self._interval_s:
                self._suppressed += 1
                return False
            suppressed, self._suppressed = self._suppressed, 0
            self._last_emitted = now
        if suppressed:
            message += f" ({suppressed} similar messages suppressed in the last {self._interval_s:g} s)"
        self._logger.warning(message, *args)
        return True

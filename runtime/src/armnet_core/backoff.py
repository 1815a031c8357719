"""The one retry policy every armnet loop uses: exponential backoff, bounded.

A loop that retries something failing (the API server's resources gone, NATS down,
a camera unplugged, ``accept`` out of file descriptors) waits ``first_s``, then twice
as long after each further failure, never more than ``max_s``, and starts over after
a success. Each loop states only its two numbers; how they grow is written here once.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class BackoffPolicy:
    """How long to wait after ``failures`` failures in a row: ``first_s * 2**(failures-1)``, at most ``max_s``."""

    first_s: float
    max_s: float

    def __post_init__(self) -> None:
        if not 0 < self.first_s <= self.max_s:
            raise ValueError(f"a backoff needs 0 < first_s <= max_s, got {self.first_s} and {self.max_s}")

    def delay(self, failures: int) -> float:
        """Pure: 0 for no failure, else the wait before the next try."""
        if failures <= 0:
            return 0.0
        # min() before the power: 2**failures overflows a float after a long outage.
        return float(min(self.max_s, self.first_s * 2.0 ** min(failures - 1, 64)))

    def start(self) -> Backoff:
        """A counter of failures in a row under this policy (one per loop)."""
        return Backoff(self)


@dataclass
class Backoff:
    """One loop's failures in a row; ``failed()`` says how long to wait, ``succeeded()`` starts over."""

    policy: BackoffPolicy
    failures: int = 0

    @property
    def failing(self) -> bool:
        return self.failures > 0

    @property
    def current_s(self) -> float:
        """The wait the last failure asked for (0 after a success)."""
        return self.policy.delay(self.failures)

    def failed(self) -> float:
        self.failures += 1
        return self.current_s

    def succeeded(self) -> None:
        self.failures = 0

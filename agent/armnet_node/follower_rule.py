"""The rule of followed jobs, pure: who is watched, for how long, and what the cancel says.

See :mod:`armnet_node.follower` (the guard that applies it) and docs/agent.md,
"Followed jobs". No I/O: the clock is passed in.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from armnet_core.api import FOLLOWER_TIMEOUT_ANNOTATION

DEFAULT_WINDOW_S = 30.0
"""The window when the annotation's value is not a number (the annotation still declares a follower)."""
MIN_WINDOW_S = 5.0
"""Below this, a couple of lost beats (2 s apart) would cancel a job whose client is alive."""
MAX_WINDOW_S = 3600.0


def heartbeat_subject(namespace: str, job_uid: str) -> str:
    """``clients.<namespace>.<jobId>.heartbeat``: where the following client beats."""
    for value, what in ((namespace, "namespace"), (job_uid, "job id")):
        if not value or any(c in value for c in " \t\r\n*>."):
            raise ValueError(f"{what} {value!r} cannot be a NATS subject token")
    return f"clients.{namespace}.{job_uid}.heartbeat"


def follower_window(annotations: Mapping[str, str], detach: bool) -> float | None:
    """The heartbeat window of a job, or None when no follower is declared (or it is detached).

    The annotation is tenant input: a non-number falls back to the default and
    the value is clamped to [MIN_WINDOW_S, MAX_WINDOW_S].
    """
    if detach or FOLLOWER_TIMEOUT_ANNOTATION not in annotations:
        return None
    try:
        window = float(annotations[FOLLOWER_TIMEOUT_ANNOTATION])
    except ValueError:
        return DEFAULT_WINDOW_S
    if not math.isfinite(window):
        return DEFAULT_WINDOW_S
    return min(max(window, MIN_WINDOW_S), MAX_WINDOW_S)


def lost_follower_message(window_s: float, silent_s: float) -> str:
    return (
        f"cancelled: the client following this job (detach: false) sent no heartbeat for "
        f"{silent_s:.1f} s (window {window_s:g} s), so it is gone; submit with detach: true "
        f"(`armnet submit --detach`, JobSpec(detach=True)) to keep a job running without a follower"
    )


class FollowerClock:
    """Silence since the last beat, on a monotonic clock the caller passes in (pure)."""

    def __init__(self, window_s: float, now: float) -> None:
        self.window_s = window_s
        self.last = now
        self.beats = 0

    def beat(self, now: float) -> None:
        self.beats += 1
        self.last = max(self.last, now)

    def pause(self, now: float) -> None:
        """The agent cannot hear beats now (its NATS link is down): the silence does not count."""
        self.last = max(self.last, now)

    def silence(self, now: float) -> float:
        return max(now - self.last, 0.0)

    def expired(self, now: float) -> bool:
        return self.silence(now) > self.window_s

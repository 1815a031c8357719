"""Leader election over a ``coordination.k8s.io`` Lease: the pure decision.

Only the leader writes; the other replicas keep their caches warm and take over
when the Lease expires. Safety does not depend on this (every write carries a
resourceVersion precondition); it only keeps replicas from wasting conflicts.

Expiry follows client-go's ``leaderelection``: a candidate never compares the
``renewTime`` another replica wrote with its own clock (the two clocks may be
hours apart). It remembers the record it last saw and the moment, on its own
monotonic clock, when that record last changed; the holder is gone for this
candidate once the record has not changed for ``leaseDurationSeconds`` of the
candidate's own time. A holder that keeps renewing changes the record each time,
whatever its clock says, so it is never taken over.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime, timedelta
from enum import StrEnum


class LeaseMove(StrEnum):
    ACQUIRE = "acquire"
    RENEW = "renew"
    FOLLOW = "follow"


@dataclass(frozen=True)
class LeaseView:
    """The Lease's spec as read: compared whole to tell whether the holder is still renewing."""

    holder: str | None
    renewed: datetime | None
    duration: timedelta
    transitions: int = 0
    acquired: datetime | None = None


@dataclass(frozen=True)
class LeaseSeen:
    """The record a candidate last saw and when it last changed, in the candidate's monotonic seconds."""

    lease: LeaseView
    changed_at: float


def observe(previous: LeaseSeen | None, lease: LeaseView, now: float) -> LeaseSeen:
    """Remember ``lease``; its clock restarts at ``now`` only if it differs from what was seen before."""
    if previous is not None and previous.lease == lease:
        return previous
    return LeaseSeen(lease, now)


def decide_lease(seen: LeaseSeen | None, me: str, now: float) -> LeaseMove:
    """May this candidate take the Lease? ``now`` is its own monotonic clock, like ``seen.changed_at``."""
    if seen is None or not seen.lease.holder:
        return LeaseMove.ACQUIRE
    if seen.lease.holder == me:
        return LeaseMove.RENEW
    if seen.changed_at + seen.lease.duration.total_seconds() < now:
        return LeaseMove.ACQUIRE
    return LeaseMove.FOLLOW

"""Leader election over a ``coordination.k8s.io`` Lease: the pure decision.

Only the leader writes; the other replicas keep their caches warm and take over
when the Lease expires. Safety does not depend on this (every write carries a
resourceVersion precondition); it only keeps replicas from wasting conflicts.
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
    holder: str | None
    renewed: datetime | None
    duration: timedelta
    transitions: int = 0


def decide_lease(lease: LeaseView | None, me: str, now: datetime) -> LeaseMove:
    if lease is None or not lease.holder:
        return LeaseMove.ACQUIRE
    if lease.holder == me:
        return LeaseMove.RENEW
    if lease.renewed is None or now - lease.renewed > lease.duration:
        return LeaseMove.ACQUIRE
    return LeaseMove.FOLLOW

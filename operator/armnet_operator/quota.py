"""Tenant quotas of cell time: the CellQuota model, usage and its decay. Pure, no I/O.

A ``CellQuota`` (cluster-scoped, like Kueue's ClusterQueue) gives one tenant (a
namespace) a nominal number of cells of one embodiment (optionally one task), a
limit on what it may borrow from the idle nominal cells of its cohort, a weight
for fair sharing and optional credits of cell-hours per period. Usage is cell
time: a cell held for one second is one cell-second. The decayed usage halves
every ``FairSharing.half_life`` so old use is forgiven gradually, as in Kueue's
admission fair sharing. Parsing from Kubernetes bodies lives in
``quota_parsing``; this module must never import kopf or kubernetes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import datetime, timedelta
from enum import StrEnum


class QuotaPeriod(StrEnum):
    """The period credits are granted for; periods start at 00:00 UTC (weeks on Monday)."""

    DAY = "Day"
    WEEK = "Week"


@dataclass(frozen=True)
class CellQuota:
    """One tenant's share of one embodiment's cells (``task`` None: any task)."""

    name: str
    namespace: str
    embodiment: str
    nominal_cells: int
    task: str | None = None
    borrowing_limit: int | None = None
    """Cells it may hold beyond ``nominal_cells``; None: as many as the cohort has idle."""
    weight: float = 1.0
    cohort: str | None = None
    credits_cell_hours: float | None = None
    period: QuotaPeriod | None = None
    preempt_lower_priority: bool = False
    """``spec.preemption.withinQuota: LowerPriority``: a waiting job preempts the tenant's lower-priority ones."""
    resource_version: str = ""


@dataclass(frozen=True)
class Usage:
    """A quota's consumption, kept in its status so it survives operator restarts."""

    decayed_cell_seconds: float = 0.0
    period_cell_seconds: float = 0.0
    period_start: datetime | None = None
    updated_at: datetime | None = None


@dataclass(frozen=True)
class QuotaObject:
    """A CellQuota as the operator's cache holds it: parsed, or why it could not be.

    ``namespace`` is ``spec.namespace`` as written (None if unreadable), so a
    namespaced operator can tell a malformed quota of its own tenants from
    another operator's. ``usage`` is read from the status either way.
    """

    name: str
    quota: CellQuota | None
    usage: Usage
    problem: str | None = None
    namespace: str | None = None
    resource_version: str = ""
    uid: str = ""
    """The object's uid, for the Events about it (``kubectl describe cellquota`` matches on it)."""


@dataclass(frozen=True)
class FairSharing:
    """How usage is weighed when tenants compete for the same cells."""

    half_life: timedelta = timedelta(hours=24)
    entry_penalty: timedelta = timedelta(minutes=10)
    """Each cell a tenant holds now counts as this much cell time on top of its usage, so a
    tenant with no history does not take every free cell in one pass (Kueue's entry penalty)."""


DEFAULT_SHARING = FairSharing()


def decay(value: float, elapsed: timedelta, half_life: timedelta) -> float:
    """``value`` after ``elapsed``: it halves every ``half_life`` (no decay for a zero half-life)."""
    if elapsed <= timedelta(0) or half_life <= timedelta(0):
        return value
    return value * float(0.5 ** (elapsed / half_life))


def period_start(now: datetime, period: QuotaPeriod) -> datetime:
    """The start of the period ``now`` falls in: 00:00 UTC that day, or that week's Monday."""
    day = now.replace(hour=0, minute=0, second=0, microsecond=0)
    return day if period is QuotaPeriod.DAY else day - timedelta(days=day.weekday())


def period_end(now: datetime, period: QuotaPeriod) -> datetime:
    return period_start(now, period) + (timedelta(days=1) if period is QuotaPeriod.DAY else timedelta(weeks=1))


def accrue_usage(
    usage: Usage, held_cells: int, now: datetime, half_life: timedelta, period: QuotaPeriod | None = None
) -> Usage:
    """Usage at ``now`` if the tenant held ``held_cells`` since ``usage.updated_at``.

    The decayed part integrates held cells under the same decay, so the result
    does not depend on how often it is called (two steps equal one step). The
    period part restarts at a period boundary and counts only time inside the
    current period.
    """
    if usage.updated_at is None or now <= usage.updated_at:
        start = period_start(now, period) if period is not None else None
        if usage.updated_at is None:
            return Usage(usage.decayed_cell_seconds, usage.period_cell_seconds, start, now)
        return usage
    elapsed = now - usage.updated_at
    seconds = elapsed.total_seconds()
    if half_life > timedelta(0):
        kept = 0.5 ** (elapsed / half_life)
        added = held_cells * half_life.total_seconds() / math.log(2) * (1 - kept)
    else:
        kept, added = 1.0, held_cells * seconds
    decayed = usage.decayed_cell_seconds * kept + added
    if period is None:
        return Usage(decayed, usage.period_cell_seconds + held_cells * seconds, None, now)
    start = period_start(now, period)
    if usage.period_start == start:
        in_period = usage.period_cell_seconds + held_cells * seconds
    else:
        in_period = held_cells * (now - max(start, usage.updated_at)).total_seconds()
    return Usage(decayed, in_period, start, now)


def credits_left(quota: CellQuota, usage: Usage, now: datetime) -> float | None:
    """Cell-seconds left this period (None: the quota grants no credits, time is not rationed)."""
    if quota.credits_cell_hours is None or quota.period is None:
        return None
    if usage.period_start != period_start(now, quota.period):
        return quota.credits_cell_hours * 3600
    return quota.credits_cell_hours * 3600 - usage.period_cell_seconds


__all__ = [
    "DEFAULT_SHARING", "CellQuota", "FairSharing", "QuotaObject", "QuotaPeriod", "Usage", "accrue_usage", "credits_left", "decay",
    "period_end", "period_start",
]

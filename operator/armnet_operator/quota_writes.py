"""What a pass writes to CellQuotas, and which quotas and usage it schedules with. Pure, no I/O.

The cache holds every CellQuota as a ``QuotaObject`` (parsed, or why not). Each
pass takes the quotas in force (well-formed, not duplicating another's scope),
each quota's usage (the newer of what its status says and what this replica
wrote last), and decides which statuses to write: at once when what
``kubectl get cellquotas`` shows changes (cells in use, borrowed, waiting, the
message), else when the usage is older than the refresh interval, so usage is
kept in the API server (and survives a restart) without a write every pass.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any

from .fairshare import index_quotas, plan_standings
from .model import Cell, Job
from .quota import DEFAULT_SHARING, CellQuota, FairSharing, QuotaObject, Usage
from .quota_parsing import standing_status


@dataclass(frozen=True)
class QuotaWrite:
    """One CellQuota status to write; ``usage`` is what it records (None: a quota not in force)."""

    name: str
    status: dict[str, Any]
    usage: Usage | None


def quotas_in_force(objects: Iterable[QuotaObject]) -> tuple[list[CellQuota], dict[str, str]]:
    """The quotas the scheduler applies, and why each other one is ignored (by name)."""
    objects = list(objects)
    problems = {o.name: o.problem for o in objects if o.quota is None and o.problem}
    kept, _ = index_quotas(o.quota for o in objects if o.quota is not None)
    for obj in objects:
        if obj.quota is not None and obj.name not in kept:
            rival = next(q.name for q in kept.values()
                         if (q.namespace, q.embodiment, q.task) == (obj.quota.namespace, obj.quota.embodiment,
                                                                    obj.quota.task))
            problems[obj.name] = (f"CellQuota {obj.name!r} is ignored: {rival!r} already covers namespace "
                                  f"{obj.quota.namespace!r}, embodiment {obj.quota.embodiment!r}"
                                  + (f", task {obj.quota.task!r}" if obj.quota.task else "")
                                  + "; delete one of them")
    return list(kept.values()), problems


def current_usage(objects: Iterable[QuotaObject], written: Mapping[str, Usage]) -> dict[str, Usage]:
    """Each quota's usage: what its status says, or what this replica wrote since, whichever is newer.

    The status is the record (read back after a restart or a change of leader);
    this replica's own last write wins only until the watch delivers it.
    """
    usage: dict[str, Usage] = {}
    for obj in objects:
        mine = written.get(obj.name)
        stored = obj.usage
        newer = mine is not None and (stored.updated_at is None or (
            mine.updated_at is not None and mine.updated_at > stored.updated_at))
        usage[obj.name] = mine if newer and mine is not None else stored
    return usage


def plan_quota_writes(
    jobs: Iterable[Job],
    cells: Iterable[Cell],
    objects: Iterable[QuotaObject],
    written_usage: Mapping[str, Usage],
    written_shown: Mapping[str, dict[str, Any]],
    now: datetime,
    refresh: timedelta,
    sharing: FairSharing = DEFAULT_SHARING,
) -> list[QuotaWrite]:
    """The status writes due this pass, in name order.

    ``written_shown`` is what this replica last wrote of each quota apart from
    its usage (empty after a restart: every quota is written once).
    """
    objects = list(objects)
    in_force, problems = quotas_in_force(objects)
    usage = current_usage(objects, written_usage)
    standings = plan_standings(jobs, cells, in_force, usage, now, sharing)
    writes: list[QuotaWrite] = []
    for obj in sorted(objects, key=lambda o: o.name):
        if not obj.name:
            continue
        standing = standings.get(obj.name)
        if standing is None:
            shown: dict[str, Any] = {"message": problems.get(obj.name, "")}
            if written_shown.get(obj.name) != shown:
                writes.append(QuotaWrite(obj.name, shown, None))
            continue
        status = {**standing_status(standing), "message": ""}
        shown = {k: v for k, v in status.items() if k != "usage"}
        last = usage[obj.name].updated_at
        stale = last is None or now - last >= refresh
        if written_shown.get(obj.name) != shown or stale:
            writes.append(QuotaWrite(obj.name, status, standing.usage))
    return writes


__all__ = ["QuotaWrite", "current_usage", "plan_quota_writes", "quotas_in_force"]

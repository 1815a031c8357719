"""Shared helpers of the fair-share tests: a plan with quotas, and what it bound."""

from __future__ import annotations

from collections.abc import Iterable, Mapping

from armnet_operator.model import Cell, Job
from armnet_operator.quota import DEFAULT_SHARING, CellQuota, FairSharing, Usage
from armnet_operator.scheduling import SchedulePlan, plan_bindings
from operator_builders import NOW, TIMING, a_cell


def plan(jobs: Iterable[Job], cells: Iterable[Cell], quotas: Iterable[CellQuota] = (),
         usage: Mapping[str, Usage] | None = None, sharing: FairSharing = DEFAULT_SHARING) -> SchedulePlan:
    return plan_bindings(jobs, cells, NOW, TIMING.heartbeat_timeout, quotas, usage, sharing)


def bound(result: SchedulePlan) -> dict[str, str]:
    return {b.job.key: b.cell.name for b in result.bindings}


def cells(count: int, prefix: str = "c") -> list[Cell]:
    return [a_cell().named(f"{prefix}{i}").ready() for i in range(count)]

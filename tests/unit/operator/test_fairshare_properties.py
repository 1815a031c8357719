"""Properties of the fair-share plan on random snapshots: quotas hold, cells are never shared, pools match."""

from __future__ import annotations

from collections import Counter
from dataclasses import replace

import pytest
from armnet_operator.fairshare import Ledger, holds_cell, plan_reclaim
from armnet_operator.model import Cell, Job, JobPhase, QueuedReason
from armnet_operator.quota import DEFAULT_SHARING, CellQuota, Usage
from fairshare_helpers import plan
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from operator_builders import BIMANUAL, NOW, SO101, a_cell, a_job, a_quota

pytestmark = pytest.mark.unit

NAMESPACES = ["ns-0", "ns-1", "ns-2", "ns-3"]
EMBODIMENTS = [SO101, BIMANUAL]
TASKS = [None, "fold"]


@st.composite
def snapshots(draw: st.DrawFn) -> tuple[list[Job], list[Cell], list[CellQuota], dict[str, Usage]]:
    cells, jobs = [], []
    for i in range(draw(st.integers(0, 10))):
        builder = a_cell().named(f"c{i}").with_embodiment(draw(st.sampled_from(EMBODIMENTS)))
        task = draw(st.sampled_from(TASKS))
        builder = builder.with_task(task) if task else builder
        if draw(st.booleans()):
            holder = (a_job().named(f"run{i}", draw(st.sampled_from(NAMESPACES)))
                      .with_embodiment(builder.cell.embodiment).running_on(f"c{i}"))
            jobs.append(holder)
            builder = builder.claimed_by(holder)
        cells.append(builder.ready())
    for i in range(draw(st.integers(0, 25))):
        builder = (a_job().named(f"q{i}", draw(st.sampled_from(NAMESPACES)))
                   .with_embodiment(draw(st.sampled_from(EMBODIMENTS)))
                   .with_priority(draw(st.integers(0, 2))).submitted_ago(draw(st.integers(1, 500))))
        task = draw(st.sampled_from(TASKS))
        jobs.append((builder.with_task(task) if task else builder).queued())
    quotas, usage = [], {}
    for ns in draw(st.lists(st.sampled_from(NAMESPACES), unique=True)):
        for emb in draw(st.lists(st.sampled_from(EMBODIMENTS), min_size=1, unique=True)):
            name = f"{ns}-{emb.replace('/', '-')}"
            builder = a_quota(ns).named(name).for_embodiment(emb).nominal(draw(st.integers(0, 3)))
            builder = builder.weighing(draw(st.sampled_from([0.5, 1.0, 3.0])))
            cohort = draw(st.sampled_from([None, "lab", "other"]))
            if cohort:
                builder = builder.in_cohort(cohort, draw(st.sampled_from([None, 0, 1, 2])))
            quotas.append(builder.build())
            usage[name] = Usage(draw(st.floats(0, 1e5)), updated_at=NOW)
    return jobs, cells, quotas, usage


def used_after(jobs: list[Job], cells: list[Cell], quotas: list[CellQuota], newly: list[Job]) -> tuple[Ledger, Counter[str]]:
    claimed = {c.current_job for c in cells if c.current_job}
    before = Ledger(quotas, [j for j in jobs if holds_cell(j, claimed)], {}, NOW, DEFAULT_SHARING)
    gained = Counter(before.tenant_of(j) for j in newly)
    for job in newly:
        before.charge(before.tenant_of(job))
    return before, gained


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(snapshots())
def test_a_plan_keeps_quotas_and_never_shares_or_mismatches_a_cell(snapshot) -> None:
    jobs, cells, quotas, usage = snapshot
    result = plan(jobs, cells, quotas, usage)
    taken = [b.cell.name for b in result.bindings]
    assert len(taken) == len(set(taken)), "a cell got two jobs"
    held = {c.name for c in cells if c.current_job}
    assert not held & set(taken), "a held cell got another job"
    for binding in result.bindings:
        assert binding.cell.embodiment == binding.job.embodiment
        assert binding.job.task is None or binding.cell.task == binding.job.task
        assert binding.job.key not in result.queued
    ledger, gained = used_after(jobs, cells, quotas, [b.job for b in result.bindings])
    for tenant in gained:
        account = ledger.accounts.get(tenant)
        assert account is not None or tenant == "", f"{tenant} (no covering quota) was bound"
        if account is None:
            continue
        quota = account.quota
        limit = quota.nominal_cells + (0 if quota.cohort is None else (10**6 if quota.borrowing_limit is None else quota.borrowing_limit))
        assert account.used <= limit, f"{quota.name} holds {account.used} > nominal+borrowing"
        if account.used > quota.nominal_cells:
            pool = (quota.cohort, quota.embodiment)
            assert ledger.cohort_used[pool] <= ledger.cohort_nominal[pool], f"{quota.name} borrowed what was not idle"


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(snapshots())
def test_reclaim_only_stops_borrowers_for_owners_within_their_share(snapshot) -> None:
    jobs, cells, quotas, usage = snapshot
    result = plan(jobs, cells, quotas, usage)
    bound = [b.job for b in result.bindings]
    holders = [j for j in jobs if j.active] + [
        replace(b.job, phase=JobPhase.DISPATCHED, cell_name=b.cell.name) for b in result.bindings]
    waiting = [j for j in jobs if j.key in result.queued and result.queued[j.key].reason is QueuedReason.ALL_CELLS_BUSY]
    decisions = plan_reclaim(holders, waiting, cells, quotas, usage, NOW)
    ledger, _ = used_after(jobs, cells, quotas, bound)
    assert len({d.job.key for d in decisions}) == len(decisions)
    stops = Counter(d.quota for d in decisions)
    for tenant, count in stops.items():
        account = ledger.accounts[tenant]
        assert account.used - count >= account.quota.nominal_cells, f"{tenant} reclaimed below its nominal share"
    for decision in decisions:
        owner = ledger.accounts[ledger.tenant_of(decision.for_job)]
        assert owner.quota.cohort == ledger.accounts[decision.quota].quota.cohort is not None

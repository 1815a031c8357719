"""Priority preemption within one tenant: a waiting job of higher priority stops one of its tenant's
lower-priority jobs at that job's next episode boundary, only where the tenant's CellQuota says so."""

from __future__ import annotations

import pytest
from armnet_operator.fairshare import Reclaim, plan_within_quota
from armnet_operator.model import Cell, Job
from armnet_operator.quota import CellQuota, QuotaPeriod, Usage, period_start
from operator_builders import NOW, a_cell, a_job, a_quota

pytestmark = pytest.mark.unit

TEAM_A = a_quota("team-a").nominal(2).preempting_lower_priorities().build()
TEAM_B = a_quota("team-b").nominal(2).preempting_lower_priorities().build()


def running(namespace: str, name: str, cell: str, priority: int = 0, bound_ago: float = 60,
            task: str | None = None) -> tuple[Job, Cell]:
    job = a_job().named(name, namespace).with_priority(priority).dispatched_to(cell, bound_ago)
    builder = a_cell().named(cell)
    return job, (builder.with_task(task) if task else builder).claimed_by(job).ready()


def decide(holders: list[tuple[Job, Cell]], waiting: list[Job], quotas: list[CellQuota] | None = None,
           decided: tuple[Reclaim, ...] = (), usage: dict[str, Usage] | None = None) -> list[str]:
    found = plan_within_quota([j for j, _ in holders], waiting, [c for _, c in holders],
                              [TEAM_A, TEAM_B] if quotas is None else quotas, usage or {}, NOW, decided)
    assert all(r.reason == "priority" for r in found)
    return [f"{r.job.key} for {r.for_job.key}" for r in found]


def waiting(name: str, priority: int, namespace: str = "team-a", task: str | None = None) -> Job:
    builder = a_job().named(name, namespace).with_priority(priority)
    return (builder.with_task(task) if task else builder).queued()


@pytest.mark.parametrize(("holders", "queue", "stopped"), [
    pytest.param([("low", 1), ("mid", 5)], [("urgent", 9)], ["team-a/low for team-a/urgent"], id="the lowest goes"),
    pytest.param([("same", 5)], [("peer", 5)], [], id="an equal priority preempts nothing"),
    pytest.param([("low", 1)], [("u1", 9), ("u2", 8)], ["team-a/low for team-a/u1"], id="the highest waiting first"),
    pytest.param([("l1", 1), ("l2", 2)], [("u1", 9), ("u2", 8)],
                 ["team-a/l1 for team-a/u1", "team-a/l2 for team-a/u2"], id="one victim each"),
    pytest.param([("l1", 1), ("l2", 2)], [("u1", 3), ("u2", 2)], ["team-a/l1 for team-a/u1"],
                 id="only strictly lower"),
])
def test_within_one_tenant(holders: list[tuple[str, int]], queue: list[tuple[str, int]], stopped: list[str]) -> None:
    held = [running("team-a", name, f"c{i}", priority) for i, (name, priority) in enumerate(holders)]
    assert decide(held, [waiting(name, priority) for name, priority in queue]) == stopped


def test_among_equal_priorities_the_most_recently_bound_job_stops() -> None:
    held = [running("team-a", "old", "c0", 1, bound_ago=600), running("team-a", "new", "c1", 1, bound_ago=10)]
    assert decide(held, [waiting("urgent", 9)]) == ["team-a/new for team-a/urgent"]


def test_never_across_tenants_whatever_the_priority() -> None:
    held = [running("team-b", "b-low", "c0", -1000)]
    assert decide(held, [waiting("a-urgent", 1000)]) == []


def test_nothing_unless_the_quota_says_lower_priority() -> None:
    held = [running("team-a", "low", "c0", 1)]
    plain = a_quota("team-a").nominal(2).build()
    assert decide(held, [waiting("urgent", 9)], [plain]) == []


def test_nothing_for_a_namespace_without_a_quota() -> None:
    held = [running("team-z", "low", "c0", 1)]
    assert decide(held, [waiting("urgent", 9, "team-z")]) == []


def test_a_tenant_out_of_credits_preempts_nothing() -> None:
    quota = a_quota("team-a").nominal(2).preempting_lower_priorities().with_credits(1.0).build()
    held = [running("team-a", "low", "c0", 1)]
    spent = Usage(period_cell_seconds=3600, period_start=period_start(NOW, QuotaPeriod.WEEK), updated_at=NOW)
    assert decide(held, [waiting("urgent", 9)], [quota], usage={quota.name: spent}) == []


def test_only_a_job_on_a_cell_the_waiting_job_can_use() -> None:
    held = [running("team-a", "folding", "c0", 1, task="fold"), running("team-a", "stacking", "c1", 2, task="stack")]
    assert decide(held, [waiting("urgent", 9, task="stack")]) == ["team-a/stacking for team-a/urgent"]


def test_a_job_already_stopping_counts_as_the_cell_on_its_way_back() -> None:
    leaving = a_job().named("leaving", "team-a").with_priority(1).cancel_requested(5).dispatched_to("c0")
    held = [(leaving, a_cell().named("c0").claimed_by(leaving).ready()), running("team-a", "low", "c1", 1)]
    assert decide(held, [waiting("urgent", 9)]) == []
    assert decide(held, [waiting("urgent", 9), waiting("next", 8)]) == ["team-a/low for team-a/next"]


def test_a_job_a_reclaim_already_serves_or_takes_is_left_to_it() -> None:
    (low, cell), owner = running("team-a", "low", "c0", 1), waiting("urgent", 9)
    reclaim = Reclaim(low, cell.name, "team-a-so101", owner, "reclaimed")
    assert decide([(low, cell)], [owner], decided=(reclaim,)) == []

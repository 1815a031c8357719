"""Reclaim: a borrowed cell goes back to its owner's waiting job, by asking one borrowing job to stop."""

from __future__ import annotations

import pytest
from armnet_operator.fairshare import plan_reclaim
from armnet_operator.model import Cell, Job
from operator_builders import NOW, a_cell, a_job, a_quota

pytestmark = pytest.mark.unit

LAB = [a_quota("team-a").nominal(1).in_cohort("lab").build(),
       a_quota("team-b").nominal(1).in_cohort("lab").build()]


def running(namespace: str, name: str, cell: str, bound_ago: float = 60, priority: int = 0,
            task: str | None = None) -> tuple[Job, Cell]:
    job = a_job().named(name, namespace).with_priority(priority).dispatched_to(cell, bound_ago)
    builder = a_cell().named(cell)
    return job, (builder.with_task(task) if task else builder).claimed_by(job).ready()


def reclaim(holders: list[tuple[Job, Cell]], waiting: list[Job], quotas=LAB):
    return plan_reclaim([j for j, _ in holders], waiting, [c for _, c in holders], quotas, {}, NOW)


def stopped(decisions) -> list[str]:
    return [d.job.key for d in decisions]


def test_a_waiting_owner_gets_back_the_cell_its_cohort_borrowed():
    holders = [running("team-b", "b-own", "c0", 600), running("team-b", "b-borrow", "c1", 60)]
    owner = a_job().named("a", "team-a").queued()
    decisions = reclaim(holders, [owner])
    assert stopped(decisions) == ["team-b/b-borrow"]
    assert (decisions[0].cell, decisions[0].quota, decisions[0].for_job) == ("c1", "team-b-so101", owner)


def test_nothing_is_reclaimed_from_a_tenant_within_its_nominal_share():
    holders = [running("team-b", "b-own", "c0")]
    assert reclaim(holders, [a_job().named("a", "team-a").queued()]) == ()


def test_an_owner_already_at_its_nominal_share_reclaims_nothing():
    holders = [running("team-a", "a-own", "c0"), running("team-b", "b-1", "c1"), running("team-b", "b-2", "c2")]
    assert reclaim(holders, [a_job().named("a", "team-a").queued()]) == ()


def test_the_lowest_priority_borrowing_job_stops_first():
    holders = [running("team-b", "b-high", "c0", 10, priority=5), running("team-b", "b-low", "c1", 600)]
    assert stopped(reclaim(holders, [a_job().named("a", "team-a").queued()])) == ["team-b/b-low"]


def test_among_equal_priorities_the_most_recently_bound_job_stops():
    holders = [running("team-b", "b-old", "c0", 600), running("team-b", "b-new", "c1", 10)]
    assert stopped(reclaim(holders, [a_job().named("a", "team-a").queued()])) == ["team-b/b-new"]


def test_a_borrowing_job_already_stopping_is_not_asked_again():
    job, cell = running("team-b", "b-borrow", "c1")
    leaving = (a_job().named("b-borrow", "team-b").cancel_requested(5).dispatched_to("c1"), cell)
    holders = [running("team-b", "b-own", "c0", 600), leaving]
    assert reclaim(holders, [a_job().named("a", "team-a").queued()]) == ()


def test_one_owner_job_takes_back_one_cell_only():
    holders = [running("team-b", f"b-{i}", f"c{i}", 600 - i) for i in range(4)]
    quotas = [a_quota("team-a").nominal(2).in_cohort("lab").build(),
              a_quota("team-b").nominal(2).in_cohort("lab").build()]
    assert len(reclaim(holders, [a_job().named("a", "team-a").queued()], quotas)) == 1


def test_an_owner_never_takes_back_more_than_its_nominal_share():
    holders = [running("team-b", f"b-{i}", f"c{i}", 600 - i) for i in range(4)]
    quotas = [a_quota("team-a").nominal(2).in_cohort("lab").build(),
              a_quota("team-b").nominal(2).in_cohort("lab").build()]
    owners = [a_job().named(f"a{i}", "team-a").queued() for i in range(3)]
    assert len(reclaim(holders, owners, quotas)) == 2


def test_the_job_stopped_is_one_on_a_cell_the_owners_job_can_use_even_if_bound_earlier():
    holders = [running("team-b", "b-early", "c0", 600, task="fold"),
               running("team-b", "b-late", "c1", 10, task="stack")]
    owner = a_job().named("a", "team-a").with_task("fold").queued()
    assert stopped(reclaim(holders, [owner])) == ["team-b/b-early"]


def test_nothing_is_reclaimed_when_no_borrowed_cell_suits_the_owners_job():
    holders = [running("team-b", "b-1", "c0", task="stack"), running("team-b", "b-2", "c1", task="stack")]
    assert reclaim(holders, [a_job().named("a", "team-a").with_task("fold").queued()]) == ()


def test_nothing_is_reclaimed_across_cohorts():
    quotas = [a_quota("team-a").nominal(1).in_cohort("lab").build(),
              a_quota("team-b").nominal(1).in_cohort("other").build()]
    holders = [running("team-b", "b-own", "c0"), running("team-b", "b-2", "c1")]
    assert reclaim(holders, [a_job().named("a", "team-a").queued()], quotas) == ()


def test_once_the_borrowed_cell_is_back_nothing_more_is_reclaimed():
    holders = [running("team-b", "b-own", "c0", 600), running("team-b", "b-borrow", "c1", 60)]
    owner = a_job().named("a", "team-a").queued()
    first = reclaim(holders, [owner])
    left = [h for h in holders if h[0].key != first[0].job.key]
    assert reclaim(left, [owner]) == ()

"""Borrowing: beyond its nominal share a tenant takes only cells its cohort leaves idle, up to its limit."""

from __future__ import annotations

import pytest
from armnet_operator.model import QueuedReason
from fairshare_helpers import bound, cells, plan
from operator_builders import BIMANUAL, a_cell, a_job, a_quota, used

pytestmark = pytest.mark.unit


def jobs_of(namespace: str, count: int, priority: int = 0):
    return [a_job().named(f"{namespace}-{i}", namespace).with_priority(priority).submitted_ago(100 - i).queued()
            for i in range(count)]


def holding(namespace: str, name: str, cell: str):
    job = a_job().named(name, namespace).running_on(cell)
    return job, a_cell().named(cell).claimed_by(job).ready()


def test_a_tenant_borrows_the_idle_nominal_cells_of_its_cohort():
    quotas = [a_quota("team-a").nominal(1).in_cohort("lab").build(),
              a_quota("team-b").nominal(2).in_cohort("lab").build()]
    assert len(bound(plan(jobs_of("team-a", 3), cells(3), quotas))) == 3


def test_without_a_cohort_a_tenant_never_borrows():
    quotas = [a_quota("team-a").nominal(1).build(), a_quota("team-b").nominal(2).build()]
    result = plan(jobs_of("team-a", 3), cells(3), quotas)
    assert len(bound(result)) == 1
    assert "no cohort to borrow from" in result.queued["team-a/team-a-1"].message


def test_a_tenant_borrows_nothing_from_another_cohort():
    quotas = [a_quota("team-a").nominal(1).in_cohort("lab").build(),
              a_quota("team-b").nominal(2).in_cohort("other").build()]
    result = plan(jobs_of("team-a", 3), cells(3), quotas)
    assert len(bound(result)) == 1
    assert "cohort 'lab' has no idle cell to lend" in result.queued["team-a/team-a-1"].message


def test_borrowing_stops_at_the_borrowing_limit():
    quotas = [a_quota("team-a").nominal(1).in_cohort("lab", borrowing_limit=1).build(),
              a_quota("team-b").nominal(3).in_cohort("lab").build()]
    result = plan(jobs_of("team-a", 4), cells(4), quotas)
    assert len(bound(result)) == 2
    assert "+ 1 borrowed and all 2 are in use" in result.queued["team-a/team-a-2"].message


def test_a_tenant_borrows_only_what_its_cohort_leaves_idle():
    running, busy = holding("team-b", "b-run", "busy")
    quotas = [a_quota("team-a").nominal(1).in_cohort("lab").build(),
              a_quota("team-b").nominal(1).in_cohort("lab").build()]
    result = plan([running, *jobs_of("team-a", 3)], [busy, *cells(3)], quotas)
    assert len(bound(result)) == 1
    assert result.queued["team-a/team-a-1"].reason is QueuedReason.QUOTA_EXHAUSTED


def test_an_owner_within_its_nominal_share_goes_before_a_borrower():
    running, busy = holding("team-a", "a-run", "busy")
    quotas = [a_quota("team-a").nominal(1).in_cohort("lab").build(),
              a_quota("team-b").nominal(1).in_cohort("lab").build()]
    borrower = jobs_of("team-a", 1, priority=9)
    owner = a_job().named("b-0", "team-b").submitted_ago(1).queued()
    much_used = {"team-b-so101": used(1e6)}  # even a far higher usage does not let the borrower first
    result = plan([running, *borrower, owner], [busy, *cells(1)], quotas, much_used)
    assert bound(result) == {"team-b/b-0": "c0"}


def test_quotas_of_another_embodiment_lend_nothing():
    quotas = [a_quota("team-a").nominal(1).in_cohort("lab").build(),
              a_quota("team-b").for_embodiment(BIMANUAL).nominal(3).in_cohort("lab").build()]
    result = plan(jobs_of("team-a", 2), cells(2), quotas)
    assert len(bound(result)) == 1

"""Scheduling rules: which waiting job gets which free cell, and why the others wait."""

from __future__ import annotations

from datetime import timedelta

import pytest
from armnet_operator.model import CellConditionType, QueuedReason
from armnet_operator.scheduling import choose_cell, plan_bindings
from operator_builders import BIMANUAL, NOW, TIMING, a_cell, a_job

pytestmark = pytest.mark.unit

HB = TIMING.heartbeat_timeout


def bound(plan):
    return {b.job.name: b.cell.name for b in plan.bindings}


def test_a_queued_job_binds_to_a_ready_cell_of_its_embodiment():
    job = a_job().named("j").queued()
    cell = a_cell().named("c").ready()
    assert bound(plan_bindings([job], [cell], NOW, HB)) == {"j": "c"}


def test_a_brand_new_job_without_status_is_schedulable():
    job = a_job().named("j").new()
    assert bound(plan_bindings([job], [a_cell().named("c").ready()], NOW, HB)) == {"j": "c"}


def test_higher_priority_goes_first_even_if_submitted_later():
    old = a_job().named("old").submitted_ago(500).queued()
    urgent = a_job().named("urgent").with_priority(10).submitted_ago(5).queued()
    plan = plan_bindings([old, urgent], [a_cell().named("c").ready()], NOW, HB)
    assert bound(plan) == {"urgent": "c"}
    assert plan.queued[old.key].reason is QueuedReason.ALL_CELLS_BUSY


def test_equal_priority_is_first_in_first_out():
    first = a_job().named("first").submitted_ago(300).queued()
    second = a_job().named("second").submitted_ago(200).queued()
    plan = plan_bindings([second, first], [a_cell().named("c").ready()], NOW, HB)
    assert bound(plan) == {"first": "c"}


def test_jobs_created_in_one_second_wait_in_the_order_they_arrived_not_by_name():
    """A creation time has whole seconds: among its jobs a late arrival never moves an earlier one back."""
    second = NOW.replace(microsecond=0) - timedelta(seconds=30)
    zed = a_job().named("zed", "tenant-z").created_at(second).arrived_ago(29.5).queued()
    bea = a_job().named("bea", "tenant-b").created_at(second).arrived_ago(29.2).queued()
    abe = a_job().named("abe", "tenant-a").created_at(second).new()  # not queued yet: arrived after both
    older = a_job().named("old", "tenant-z").created_at(second - timedelta(seconds=1)).arrived_ago(31).queued()
    plan = plan_bindings([abe, bea, zed, older], [a_cell().named("c").claimed_by("x/y").ready()], NOW, HB)
    positions = {key.split("/")[1]: entry.position for key, entry in plan.queued.items()}
    assert positions == {"old": 1, "zed": 2, "bea": 3, "abe": 4}


def test_priority_and_creation_still_come_before_arrival():
    second = NOW.replace(microsecond=0) - timedelta(seconds=30)
    early = a_job().named("early").created_at(second - timedelta(seconds=5)).arrived_ago(1).queued()
    urgent = a_job().named("urgent").with_priority(2).created_at(second).new()
    late = a_job().named("late").created_at(second).arrived_ago(29).queued()
    plan = plan_bindings([late, early, urgent], [a_cell().named("c").claimed_by("x/y").ready()], NOW, HB)
    positions = {key.split("/")[1]: entry.position for key, entry in plan.queued.items()}
    assert positions == {"urgent": 1, "early": 2, "late": 3}


def test_a_job_with_a_task_only_binds_to_a_cell_of_that_task():
    job = a_job().named("j").with_task("fold").queued()
    other = a_cell().named("stack").with_task("stack").ready()
    right = a_cell().named("fold").with_task("fold").ready()
    assert bound(plan_bindings([job], [other, right], NOW, HB)) == {"j": "fold"}


def test_a_job_without_a_task_binds_to_any_cell_of_the_embodiment():
    job = a_job().named("j").queued()
    cell = a_cell().named("c").with_task("fold").ready()
    assert choose_cell(job, [cell], NOW, HB) == cell


def test_a_cordoned_cell_takes_no_new_job():
    plan = plan_bindings([a_job().queued()], [a_cell().cordoned().ready()], NOW, HB)
    assert plan.bindings == ()
    assert next(iter(plan.queued.values())).reason is QueuedReason.ALL_CELLS_UNAVAILABLE


def test_a_cell_with_a_stale_heartbeat_takes_no_new_job():
    plan = plan_bindings([a_job().queued()], [a_cell().silent_for(31).ready()], NOW, HB)
    assert plan.bindings == ()
    assert next(iter(plan.queued.values())).reason is QueuedReason.ALL_CELLS_UNAVAILABLE


def test_a_faulted_cell_takes_no_new_job():
    cell = a_cell().failing(CellConditionType.INTERLOCK_CLEAR).ready()
    assert choose_cell(a_job().queued(), [cell], NOW, HB) is None


def test_a_claimed_cell_is_busy():
    cell = a_cell().claimed_by("other/job").ready()
    plan = plan_bindings([a_job().queued()], [cell], NOW, HB)
    assert plan.bindings == ()
    assert next(iter(plan.queued.values())).reason is QueuedReason.ALL_CELLS_BUSY


def test_a_cell_named_by_an_active_job_is_busy_even_without_a_claim():
    cell = a_cell().named("c").ready()
    running = a_job().running_on("c")
    assert bound(plan_bindings([running, a_job().queued()], [cell], NOW, HB)) == {}


def test_a_job_that_matches_no_free_cell_does_not_block_the_jobs_behind_it():
    blocked = a_job().named("bimanual").with_embodiment(BIMANUAL).with_priority(9).queued()
    behind = a_job().named("single").queued()
    plan = plan_bindings([blocked, behind], [a_cell().named("c").ready()], NOW, HB)
    assert bound(plan) == {"single": "c"}


def test_no_cell_of_the_embodiment_says_so():
    plan = plan_bindings([a_job().with_embodiment(BIMANUAL).queued()], [a_cell().ready()], NOW, HB)
    assert next(iter(plan.queued.values())).reason is QueuedReason.NO_CELL_FOR_EMBODIMENT


def test_no_cell_of_the_embodiment_and_task_says_so():
    job = a_job().with_task("fold").queued()
    plan = plan_bindings([job], [a_cell().with_task("stack").ready()], NOW, HB)
    assert plan.queued[job.key].reason is QueuedReason.NO_CELL_FOR_EMBODIMENT_AND_TASK
    assert "drop spec.task" in plan.queued[job.key].message


def test_queue_position_counts_only_jobs_competing_for_the_same_cells():
    cells = [a_cell().with_task("fold").claimed_by("x/y").ready()]
    fold1 = a_job().named("fold1").with_task("fold").submitted_ago(50).queued()
    any1 = a_job().named("any1").submitted_ago(40).queued()
    fold2 = a_job().named("fold2").with_task("fold").submitted_ago(30).queued()
    stack = a_job().named("stack").with_task("stack").submitted_ago(20).queued()
    bimanual = a_job().named("bi").with_embodiment(BIMANUAL).submitted_ago(60).queued()
    plan = plan_bindings([fold1, any1, fold2, stack, bimanual], cells, NOW, HB)
    positions = {key.split("/")[1]: entry.position for key, entry in plan.queued.items()}
    assert positions == {"fold1": 1, "any1": 2, "fold2": 3, "stack": 2, "bi": 1}


def test_jobs_being_cancelled_or_already_dispatched_are_not_scheduled():
    cells = [a_cell().named("c1").ready(), a_cell().named("c2").ready()]
    cancelled = a_job().cancelled_by_user().queued()
    deleting = a_job().being_deleted().queued()
    plan = plan_bindings([cancelled, deleting], cells, NOW, HB)
    assert plan.bindings == () and plan.queued == {}


def test_a_job_with_an_outstanding_claim_waits_for_the_repair_instead_of_taking_a_second_cell():
    job = a_job().named("j").queued()
    stale = a_cell().named("stale").claimed_by(job, seconds_ago=1).ready()
    free = a_cell().named("free").ready()
    plan = plan_bindings([job], [stale, free], NOW, HB)
    assert plan.bindings == ()
    assert plan.queued[job.key].reason is QueuedReason.WAITING_FOR_CELL_RELEASE


def test_many_jobs_fill_every_free_cell_exactly_once():
    cells = [a_cell().named(f"c{i}").ready() for i in range(5)]
    jobs = [a_job().named(f"j{i}").submitted_ago(100 - i).queued() for i in range(8)]
    plan = plan_bindings(jobs, cells, NOW, HB)
    assert sorted(bound(plan).values()) == [f"c{i}" for i in range(5)]
    assert sorted(bound(plan)) == [f"j{i}" for i in range(5)]
    assert [plan.queued[j.key].position for j in jobs[5:]] == [1, 2, 3]

"""The latest start of a waiting job: every job running and ahead uses its whole timeout and grace."""

from __future__ import annotations

from datetime import timedelta

import pytest
from armnet_operator.estimate import Seat, latest_starts, seats
from armnet_operator.model import QueuedReason
from armnet_operator.scheduling import plan_bindings
from operator_builders import NOW, TIMING, a_cell, a_job

pytestmark = pytest.mark.unit

HB = TIMING.heartbeat_timeout


def at(seconds: float):  # noqa: ANN201 - a datetime
    return NOW + timedelta(seconds=seconds)


def test_a_cell_is_free_when_its_running_job_would_be_killed_at_the_end_of_grace():
    cell = a_cell().named("c").with_grace(10).claimed_by("tenant-a/run").build()
    running = a_job().named("run").with_timeout(300).started_ago(100).running_on("c")
    [seat] = seats([cell], {"c": running}, NOW)
    assert seat.free_at == at(300 + 10 - 100)


def test_a_job_bound_but_not_started_counts_from_its_binding_and_an_overdue_one_frees_the_cell_now():
    cell = a_cell().named("c").with_grace(10).build()
    bound = a_job().named("b").with_timeout(120).dispatched_to("c", seconds_ago=30)
    overdue = a_job().named("o").with_timeout(60).started_ago(600).running_on("c")
    assert seats([cell], {"c": bound}, NOW)[0].free_at == at(120 + 10 - 30)
    assert seats([cell], {"c": overdue}, NOW)[0].free_at == NOW


def test_each_waiting_job_takes_the_cell_that_frees_first_in_queue_order():
    a, b = a_cell().named("a").with_grace(0).build(), a_cell().named("b").with_grace(0).build()
    first, second, third = (a_job().named(n).with_timeout(100).queued() for n in ("first", "second", "third"))
    starts = latest_starts([first, second, third], [Seat(a, at(50)), Seat(b, at(20))])
    assert starts == {first.key: at(20), second.key: at(50), third.key: at(120)}


def test_a_job_with_a_task_waits_only_for_the_cells_of_its_task():
    plain, tasked = a_cell().named("plain").build(), a_cell().named("tasked").with_task("pick").build()
    job = a_job().named("j").with_task("pick").queued()
    assert latest_starts([job], [Seat(plain, NOW), Seat(tasked, at(300))]) == {job.key: at(300)}


def test_a_job_without_a_task_takes_a_tasked_cell_and_the_tasked_job_behind_it_waits_for_that_cell_again():
    tasked = a_cell().named("tasked").with_task("pick").with_grace(5).build()
    untasked = a_job().named("any").with_timeout(60).queued()
    picker = a_job().named("picker").with_task("pick").queued()
    starts = latest_starts([untasked, picker], [Seat(tasked, at(10))])
    assert starts == {untasked.key: at(10), picker.key: at(10 + 60 + 5)}


def test_a_job_no_cell_matches_gets_no_estimate():
    job = a_job().named("j").with_embodiment("nobody/has-this").queued()
    assert latest_starts([job], [Seat(a_cell().named("c").build(), NOW)]) == {}


def test_the_plan_gives_jobs_waiting_for_busy_cells_their_latest_start_and_the_rest_none():
    busy = a_cell().named("busy").with_grace(10).claimed_by("tenant-a/run").build()
    running = a_job().named("run").with_timeout(200).started_ago(50).running_on("busy")
    first = a_job().named("first").with_timeout(100).submitted_ago(300).queued()
    second = a_job().named("second").with_timeout(100).submitted_ago(200).queued()
    stranded = a_job().named("stranded").with_task("nowhere").queued()
    plan = plan_bindings([running, first, second, stranded], [busy], NOW, HB)
    assert plan.queued[first.key].latest_start == at(200 + 10 - 50)
    assert plan.queued[second.key].latest_start == at(200 + 10 - 50 + 100 + 10)
    assert plan.queued[stranded.key].reason is QueuedReason.NO_CELL_FOR_EMBODIMENT_AND_TASK
    assert plan.queued[stranded.key].latest_start is None


def test_a_cell_bound_in_this_pass_holds_its_new_job_for_its_whole_timeout():
    free = a_cell().named("free").with_grace(10).build()
    first = a_job().named("first").with_timeout(60).submitted_ago(300).queued()
    second = a_job().named("second").submitted_ago(200).queued()
    plan = plan_bindings([first, second], [free], NOW, HB)
    assert [b.job.name for b in plan.bindings] == ["first"]
    assert plan.queued[second.key].latest_start == at(60 + 10)

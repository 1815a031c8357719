"""The start of a waiting job: at the latest (every job running and ahead uses its whole timeout and
grace) and likely (each takes its embodiment's typical recent run, never more)."""

from __future__ import annotations

from datetime import timedelta

import pytest
from armnet_operator.estimate import (
    RECENT_RUNS,
    Seat,
    likely_occupancy,
    queue_starts,
    seats,
    typical_runs,
)
from armnet_operator.model import CellQueue, JobPhase, QueuedReason
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
    starts = queue_starts([first, second, third], [Seat(a, at(50)), Seat(b, at(20))])
    assert starts == {first.key: at(20), second.key: at(50), third.key: at(120)}


def test_a_job_with_a_task_waits_only_for_the_cells_of_its_task():
    plain, tasked = a_cell().named("plain").build(), a_cell().named("tasked").with_task("pick").build()
    job = a_job().named("j").with_task("pick").queued()
    assert queue_starts([job], [Seat(plain, NOW), Seat(tasked, at(300))]) == {job.key: at(300)}


def test_a_job_without_a_task_takes_a_tasked_cell_and_the_tasked_job_behind_it_waits_for_that_cell_again():
    tasked = a_cell().named("tasked").with_task("pick").with_grace(5).build()
    untasked = a_job().named("any").with_timeout(60).queued()
    picker = a_job().named("picker").with_task("pick").queued()
    starts = queue_starts([untasked, picker], [Seat(tasked, at(10))])
    assert starts == {untasked.key: at(10), picker.key: at(10 + 60 + 5)}


def test_a_job_no_cell_matches_gets_no_estimate():
    job = a_job().named("j").with_embodiment("nobody/has-this").queued()
    assert queue_starts([job], [Seat(a_cell().named("c").build(), NOW)]) == {}


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


def a_run(name: str, seconds: float, *, ended_ago: float = 10, embodiment: str = "lerobot/so-101",
          phase: JobPhase = JobPhase.SUCCEEDED):  # noqa: ANN201 - a finished Job
    """A finished job that ran ``seconds``, ending ``ended_ago`` seconds before NOW."""
    return a_job().named(name).with_embodiment(embodiment).started_ago(ended_ago + seconds).finished(
        phase, seconds_ago=ended_ago)


def test_an_embodiment_s_typical_run_is_the_median_of_its_latest_finished_runs_whatever_their_outcome():
    runs = [a_run("a", 30), a_run("b", 90, phase=JobPhase.FAILED), a_run("c", 60, phase=JobPhase.TIMEOUT),
            a_run("other", 999, embodiment="lerobot/bimanual_so101")]
    unfinished = a_job().named("running").started_ago(5000).running_on("c")
    typical = typical_runs([*runs, unfinished, a_job().named("q").queued()])
    assert typical == {"lerobot/so-101": timedelta(seconds=60),
                       "lerobot/bimanual_so101": timedelta(seconds=999)}


def test_only_the_latest_runs_count_so_a_job_that_got_faster_is_seen_as_faster():
    old = [a_run(f"old-{i}", 600, ended_ago=10_000 + i) for i in range(RECENT_RUNS)]
    new = [a_run(f"new-{i}", 60, ended_ago=100 + i) for i in range(RECENT_RUNS // 2 + 1)]
    assert typical_runs([*old, *new]) == {"lerobot/so-101": timedelta(seconds=60)}


def test_a_likely_occupancy_is_the_typical_run_never_more_than_timeout_and_grace():
    cell = a_cell().named("c").with_grace(10).build()
    likely = likely_occupancy({"lerobot/so-101": timedelta(seconds=60)})
    assert likely(a_job().named("long").with_timeout(300).queued(), cell) == timedelta(seconds=60)
    assert likely(a_job().named("short").with_timeout(20).queued(), cell) == timedelta(seconds=20 + 10)
    assert likely(a_job().named("unknown").with_embodiment("x/y").with_timeout(300).queued(), cell) == \
        timedelta(seconds=300 + 10)


def test_the_plan_gives_a_likely_start_from_recent_runs_and_the_latest_start_from_timeouts():
    busy = a_cell().named("busy").with_grace(10).claimed_by("tenant-a/run").build()
    running = a_job().named("run").with_timeout(600).started_ago(50).running_on("busy")
    first = a_job().named("first").with_timeout(600).submitted_ago(300).queued()
    second = a_job().named("second").with_timeout(600).submitted_ago(200).queued()
    history = [a_run(f"ran-{i}", 120) for i in range(3)]
    plan = plan_bindings([running, first, second, *history], [busy], NOW, HB)
    assert plan.queued[first.key].latest_start == at(600 + 10 - 50)
    assert plan.queued[first.key].likely_start == at(120 - 50)
    assert plan.queued[second.key].latest_start == at(600 + 10 - 50 + 600 + 10)
    assert plan.queued[second.key].likely_start == at(120 - 50 + 120)


def test_a_running_job_past_its_typical_run_counts_as_ending_now_and_no_history_means_the_latest_start():
    busy = a_cell().named("busy").with_grace(10).claimed_by("tenant-a/run").build()
    running = a_job().named("run").with_timeout(600).started_ago(500).running_on("busy")
    waiting = a_job().named("waiting").with_timeout(600).submitted_ago(300).queued()
    plan = plan_bindings([running, waiting, a_run("ran", 120)], [busy], NOW, HB)
    assert plan.queued[waiting.key].likely_start == NOW
    plan = plan_bindings([running, waiting], [busy], NOW, HB)
    assert plan.queued[waiting.key].likely_start == plan.queued[waiting.key].latest_start == at(600 + 10 - 500)


def test_each_cell_counts_the_jobs_that_could_run_on_it_and_says_when_its_job_likely_ends_and_at_the_latest():
    picker = a_cell().named("picker").with_task("pick").with_grace(10).claimed_by("tenant-a/run").build()
    plain = a_cell().named("plain").with_grace(10).claimed_by("tenant-a/other").build()
    idle = a_cell().named("idle").with_embodiment("lerobot/bimanual_so101").build()
    running = a_job().named("run").with_task("pick").with_timeout(600).started_ago(50).running_on("picker")
    other = a_job().named("other").with_timeout(600).started_ago(10).running_on("plain")
    untasked = a_job().named("any").submitted_ago(300).queued()
    tasked = a_job().named("pick-1").with_task("pick").submitted_ago(200).queued()
    plan = plan_bindings([running, other, untasked, tasked, *(a_run(f"ran-{i}", 120) for i in range(3))],
                         [picker, plain, idle], NOW, HB)
    picker_queue, plain_queue = plan.cell_queues["picker"], plan.cell_queues["plain"]
    # Both waiting jobs could run on the task's cell; only the untasked one on the plain cell.
    assert (picker_queue.waiting_jobs, plain_queue.waiting_jobs) == (2, 1)
    assert (picker_queue.likely_free, picker_queue.latest_free) == (at(120 - 50), at(600 + 10 - 50))
    assert (plain_queue.likely_free, plain_queue.latest_free) == (at(120 - 10), at(600 + 10 - 10))
    # A cell nobody holds has no free time, and no job waits for its embodiment.
    assert plan.cell_queues["idle"] == CellQueue(0, None, None)


def test_a_cell_bound_in_this_pass_frees_from_its_binding():
    free = a_cell().named("free").with_grace(10).build()
    first = a_job().named("first").with_timeout(60).submitted_ago(300).queued()
    second = a_job().named("second").submitted_ago(200).queued()
    plan = plan_bindings([first, second], [free], NOW, HB)
    assert plan.cell_queues["free"] == CellQueue(1, at(60 + 10), at(60 + 10))

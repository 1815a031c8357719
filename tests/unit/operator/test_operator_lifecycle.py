"""Lifecycle rules: repair half-done bindings, offline cells, cancellation, finalizers, TTL."""

from __future__ import annotations

import pytest
from armnet_operator.lifecycle import (
    AddFinalizer,
    DeleteJob,
    FinishJob,
    ReleaseCell,
    RemoveFinalizer,
    RequestCancel,
    RequeueJob,
    SetCellPhase,
    plan_lifecycle,
)
from armnet_operator.model import CellPhase, JobPhase
from operator_builders import NOW, TIMING, a_cell, a_job

pytestmark = pytest.mark.unit


def plan(jobs, cells):
    return plan_lifecycle(jobs, cells, NOW, TIMING)


def of_type(actions, kind):
    return [a for a in actions if isinstance(a, kind)]


def test_a_cell_claimed_for_a_job_that_never_got_bound_is_released_after_the_grace():
    job = a_job().queued()
    cell = a_cell().claimed_by(job, seconds_ago=11).ready()
    [release] = of_type(plan([job], [cell]), ReleaseCell)
    assert release.phase is CellPhase.READY and "never completed" in release.reason


def test_a_fresh_claim_is_left_alone_while_the_binder_finishes_its_second_write():
    job = a_job().queued()
    cell = a_cell().claimed_by(job, seconds_ago=2).ready()
    assert of_type(plan([job], [cell]), ReleaseCell) == []


def test_a_claim_for_a_deleted_job_is_released():
    cell = a_cell().claimed_by("tenant-a/gone", seconds_ago=30).ready()
    assert "no longer exists" in of_type(plan([], [cell]), ReleaseCell)[0].reason


def test_a_finished_job_releases_its_cell_at_once():
    job = a_job().finished(cell="c")
    cell = a_cell().named("c").claimed_by(job, seconds_ago=1).ready()
    assert len(of_type(plan([job], [cell]), ReleaseCell)) == 1


def test_a_running_job_keeps_its_cell():
    job = a_job().running_on("c")
    cell = a_cell().named("c").claimed_by(job).ready()
    assert plan([job], [cell]) == ()


def test_a_dispatched_job_whose_cell_does_not_name_it_goes_back_to_the_queue():
    job = a_job().dispatched_to("c", seconds_ago=20)
    cell = a_cell().named("c").ready()
    [requeue] = of_type(plan([job], [cell]), RequeueJob)
    assert "does not hold" in requeue.message


def test_a_dispatched_job_on_an_offline_cell_goes_back_to_the_queue():
    job = a_job().dispatched_to("c")
    cell = a_cell().named("c").claimed_by(job).silent_for(45).ready()
    [requeue] = of_type(plan([job], [cell]), RequeueJob)
    assert "offline" in requeue.message


def test_an_offline_cell_is_marked_offline():
    cell = a_cell().silent_for(45).ready()
    assert of_type(plan([], [cell]), SetCellPhase)[0].phase is CellPhase.OFFLINE


def test_a_running_job_survives_a_short_outage():
    job = a_job().running_on("c")
    cell = a_cell().named("c").claimed_by(job).silent_for(45).ready()
    assert of_type(plan([job], [cell]), FinishJob) == []


def test_a_running_job_on_a_cell_lost_past_the_grace_fails_with_the_reason():
    job = a_job().running_on("c")
    cell = a_cell().named("c").claimed_by(job).silent_for(91).ready()
    [finish] = of_type(plan([job], [cell]), FinishJob)
    assert finish.phase is JobPhase.FAILED and finish.error == "cell c lost"


def test_a_queued_job_is_cancelled_at_once_saying_so():
    job = a_job().cancelled_by_user().queued()
    [finish] = of_type(plan([job], []), FinishJob)
    assert finish.phase is JobPhase.CANCELLED and finish.error == "the job was cancelled before it started"


def test_a_running_job_is_asked_to_stop_gracefully():
    job = a_job().cancelled_by_user().running_on("c")
    cell = a_cell().named("c").claimed_by(job).ready()
    assert of_type(plan([job], [cell]), RequestCancel) == [RequestCancel(job)]


def test_a_cancel_the_agent_is_still_handling_is_not_forced():
    job = a_job().cancel_requested(seconds_ago=300).running_on("c")
    cell = a_cell().named("c").claimed_by(job).ready()
    assert of_type(plan([job], [cell]), FinishJob) == []


def test_a_cancel_on_a_cell_whose_agent_is_gone_is_forced_after_the_timeout():
    job = a_job().cancel_requested(seconds_ago=61).running_on("c")
    cell = a_cell().named("c").claimed_by(job).silent_for(100).ready()
    [finish] = of_type(plan([job], [cell]), FinishJob)
    assert finish.phase is JobPhase.CANCELLED and "did not report" in finish.error


def test_deleting_a_queued_job_cancels_it_first():
    job = a_job().being_deleted().queued()
    [finish] = of_type(plan([job], []), FinishJob)
    assert finish.phase is JobPhase.CANCELLED and finish.error == "the job was deleted before it started"
    assert of_type(plan([job], []), RemoveFinalizer) == []


def test_the_finalizer_goes_only_once_the_cell_is_released():
    job = a_job().being_deleted().finished(JobPhase.CANCELLED, cell="c")
    claimed = a_cell().named("c").claimed_by(job).ready()
    released = a_cell().named("c").ready()
    assert of_type(plan([job], [claimed]), RemoveFinalizer) == []
    assert of_type(plan([job], [released]), RemoveFinalizer) == [RemoveFinalizer(job)]


def test_a_finished_job_loses_the_finalizer_once_its_cell_is_released_without_being_deleted():
    """Kept after it ends, it must still delete at once when no operator runs any more."""
    job = a_job().finished(JobPhase.SUCCEEDED, seconds_ago=1, cell="c")
    claimed = a_cell().named("c").claimed_by(job).ready()
    released = a_cell().named("c").ready()
    assert of_type(plan([job], [claimed]), RemoveFinalizer) == []
    assert of_type(plan([job], [released]), RemoveFinalizer) == [RemoveFinalizer(job)]


def test_a_finished_job_whose_cell_is_gone_loses_the_finalizer():
    job = a_job().finished(JobPhase.FAILED, seconds_ago=1, cell="gone")
    assert of_type(plan([job], []), RemoveFinalizer) == [RemoveFinalizer(job)]


def test_a_finished_job_past_its_ttl_loses_the_finalizer_then_is_deleted():
    job = a_job().with_ttl(5).finished(seconds_ago=6)
    assert of_type(plan([job], []), RemoveFinalizer | DeleteJob) == [RemoveFinalizer(job), DeleteJob(job)]


def test_a_job_holding_a_cell_gets_the_finalizer_and_a_waiting_one_none():
    bound = a_job().named("bound").without_finalizer().dispatched_to("c1")
    claimed = a_job().named("claimed").without_finalizer().queued()
    waiting = a_job().named("waiting").without_finalizer().queued()
    cells = [a_cell().named("c1").claimed_by(bound).ready(), a_cell().named("c2").claimed_by(claimed).ready()]
    assert of_type(plan([bound, claimed, waiting], cells), AddFinalizer) == [AddFinalizer(bound), AddFinalizer(claimed)]


def test_a_finished_job_without_the_finalizer_gets_none_but_still_frees_its_cell():
    job = a_job().named("j").without_finalizer().finished(JobPhase.SUCCEEDED, seconds_ago=1, cell="c")
    claimed = a_cell().named("c").claimed_by(job).ready()
    actions = plan([job], [claimed])
    assert of_type(actions, AddFinalizer) == []
    assert [a.cell.name for a in of_type(actions, ReleaseCell)] == ["c"]


def test_a_finished_job_is_deleted_after_its_own_ttl():
    assert of_type(plan([a_job().with_ttl(5).finished(seconds_ago=6)], []), DeleteJob)
    assert not of_type(plan([a_job().with_ttl(60).finished(seconds_ago=6)], []), DeleteJob)


def test_a_finished_job_without_a_ttl_uses_the_default():
    assert of_type(plan([a_job().finished(seconds_ago=3601)], []), DeleteJob)
    assert not of_type(plan([a_job().finished(seconds_ago=3599)], []), DeleteJob)

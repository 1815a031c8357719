"""A replica whose watch lags must not undo another replica's binding.

The repair frees a claim its job does not confirm once ``claim_grace`` has
passed. A replica that decides that on a lagging view (the job still queued,
or not delivered yet) would free the cell of a job that is dispatched there:
the job is then requeued and bound again, and meanwhile the scheduler sees the
cell as free. The writer therefore asks the server for the job before such a
release; these tests pin both sides of that decision.
"""

from __future__ import annotations

from dataclasses import replace
from datetime import timedelta

import pytest
from armnet_operator.model import Timing
from armnet_operator.reconcile import Limits, Memory, Outcome, reconcile_once
from operator_world import Crash, World

pytestmark = pytest.mark.unit

TIMING = Timing(
    heartbeat_timeout=timedelta(seconds=30),
    claim_grace=timedelta(seconds=10),
    lost_grace=timedelta(seconds=60),
    cancel_force_after=timedelta(seconds=60),
    default_ttl=None,
)


def bound_job_seen_late() -> tuple[World, list, list]:
    """One cell, one job bound to it; and the job list as a lagging replica saw it before."""
    world = World()
    world.add_cell("c0", "so-101", None)
    world.heartbeat("c0")
    world.submit("j", "so-101", None, 0)
    stale_jobs, _ = world.snapshot()
    jobs, cells = world.snapshot()
    reconcile_once(jobs, cells, world.now, TIMING, world, Memory(), Limits())
    assert world.jobs["t/j"]["status"]["phase"] == "dispatched"
    world.tick(TIMING.claim_grace.total_seconds() + 1)
    world.heartbeat("c0")
    _, fresh_cells = world.snapshot()
    return world, stale_jobs, fresh_cells


def lagging_pass(world: World, jobs: list, cells: list) -> Outcome:
    return reconcile_once(jobs, cells, world.now, TIMING, world, Memory(), Limits())


def test_a_claim_whose_job_still_looks_queued_here_stands_when_the_server_has_it_bound() -> None:
    world, stale_jobs, cells = bound_job_seen_late()
    outcome = lagging_pass(world, stale_jobs, cells)
    assert world.cells["c0"]["status"]["currentJob"] == "t/j"
    assert world.jobs["t/j"]["status"]["phase"] == "dispatched"
    assert outcome.requeued == 0


def test_a_claim_whose_job_has_not_reached_this_replica_yet_stands() -> None:
    world, _, cells = bound_job_seen_late()
    lagging_pass(world, [], cells)
    assert world.cells["c0"]["status"]["currentJob"] == "t/j"


def test_a_claim_whose_bind_never_happened_is_released_after_the_grace() -> None:
    world, stale_jobs, cells = bound_job_seen_late()
    del world.jobs["t/j"]["status"]["phase"]  # as if the binder crashed between claim and bind
    world.jobs["t/j"]["status"].pop("cellName", None)
    lagging_pass(world, stale_jobs, cells)
    assert world.cells["c0"]["status"].get("currentJob") is None


def test_a_claim_whose_job_is_gone_from_the_server_is_released_after_the_grace() -> None:
    world, stale_jobs, cells = bound_job_seen_late()
    del world.jobs["t/j"]
    lagging_pass(world, stale_jobs, cells)
    assert world.cells["c0"]["status"].get("currentJob") is None


def test_a_dispatched_job_whose_cell_lost_its_claim_is_requeued_counted_and_bound_again() -> None:
    world, _, _ = bound_job_seen_late()
    world.cells["c0"]["status"]["currentJob"] = None
    world.cells["c0"]["metadata"]["resourceVersion"] = "999"
    jobs, cells = world.snapshot()
    outcome = lagging_pass(world, jobs, cells)
    assert outcome.requeued == 1
    assert ("t/j", "Requeued") in world.events
    assert [job.name for job, _ in outcome.bound] == ["j"], "the freed cell takes it back in the same pass"
    assert world.cells["c0"]["status"]["currentJob"] == "t/j"


def a_ready_cell() -> World:
    world = World()
    world.add_cell("c0", "so-101", None)
    world.heartbeat("c0")
    jobs, cells = world.snapshot()
    reconcile_once(jobs, cells, world.now, TIMING, world, Memory(), Limits())  # the cell gets its phase
    return world


def bound_without_finalizer() -> World:
    """A job another replica claimed a cell for and bound, then crashed before its finalizer."""
    world = a_ready_cell()
    world.submit("j", "so-101", None, 0)
    jobs, cells = world.snapshot()
    world.crash_after = 2  # claim, bind; the finalizer write crashes
    with pytest.raises(Crash):
        reconcile_once(jobs, cells, world.now, TIMING, world, Memory(), Limits())
    world.crash_after = None
    assert world.jobs["t/j"]["status"]["phase"] == "dispatched"
    assert not world.jobs["t/j"]["metadata"].get("finalizers")
    return world


def test_a_stale_replica_adding_the_finalizer_does_not_put_a_bound_job_back_in_the_queue() -> None:
    """The finalizer lands without a resourceVersion; the queue write decided on the stale view must not follow."""
    world = a_ready_cell()
    world.submit("j", "so-101", None, 0)
    stale_jobs, _ = world.snapshot()  # j as submitted: no phase, no finalizer
    jobs, cells = world.snapshot()
    world.crash_after = 2
    with pytest.raises(Crash):
        reconcile_once(jobs, cells, world.now, TIMING, world, Memory(), Limits())
    world.crash_after = None
    _, fresh_cells = world.snapshot()  # c0 now holds the claim: this replica would queue j
    lagging_pass(world, stale_jobs, fresh_cells)
    status = world.jobs["t/j"]["status"]
    assert (status["phase"], status["cellName"]) == ("dispatched", "c0")
    assert world.jobs["t/j"]["metadata"]["finalizers"], "the finalizer itself is safe to add and stays"


def test_a_stale_replica_adding_the_finalizer_does_not_requeue_a_job_that_started_meanwhile() -> None:
    world = bound_without_finalizer()
    stale_jobs, cells = world.snapshot()  # j dispatched, no finalizer
    world.agent_set_phase("t/j", "running")
    world.tick(TIMING.claim_grace.total_seconds() + 1)
    world.heartbeat("c0")
    # This replica also missed the claim: its view says c0 does not hold j, so j looks stranded.
    _, fresh_cells = world.snapshot()
    unclaimed = [replace(c, current_job=None, claimed_at=None) for c in fresh_cells]
    outcome = lagging_pass(world, stale_jobs, unclaimed)
    assert world.jobs["t/j"]["status"]["phase"] == "running"
    assert world.jobs["t/j"]["status"]["cellName"] == "c0"
    assert outcome.requeued == 0 and ("t/j", "Requeued") not in world.events


def running_job_on_c0() -> tuple[World, list, list]:
    """j running on c0 (claimed, heartbeating) past the claim grace; the fresh view of both."""
    world = bound_without_finalizer()
    world.agent_set_phase("t/j", "running")
    world.tick(TIMING.claim_grace.total_seconds() + 1)
    world.heartbeat("c0")
    jobs, cells = world.snapshot()
    return world, jobs, cells


def test_a_running_job_is_not_failed_on_a_cell_view_that_lags_behind_its_claim() -> None:
    """The job watch is current, the cell watch lags: here c0 holds no claim; the server's c0 holds j's."""
    world, jobs, cells = running_job_on_c0()
    unclaimed = [replace(c, current_job=None, claimed_at=None) for c in cells]
    lagging_pass(world, jobs, unclaimed)
    assert world.jobs["t/j"]["status"]["phase"] == "running"
    assert ("t/j", "ClaimNotHeld") not in world.events


def test_a_running_job_is_not_failed_on_a_heartbeat_this_view_has_not_seen() -> None:
    world, jobs, stale_cells = running_job_on_c0()
    world.tick((TIMING.heartbeat_timeout + TIMING.lost_grace).total_seconds() + 1)
    world.heartbeat("c0")  # the agent kept beating; this replica's view stopped at the earlier beat
    lagging_pass(world, jobs, stale_cells)
    assert world.jobs["t/j"]["status"]["phase"] == "running"


def test_a_running_job_whose_cell_lost_the_claim_on_the_server_fails_with_the_reason() -> None:
    world, _, _ = running_job_on_c0()
    world.cells["c0"]["status"]["currentJob"] = None
    world.cells["c0"]["metadata"]["resourceVersion"] = "999"
    jobs, cells = world.snapshot()
    lagging_pass(world, jobs, cells)
    status = world.jobs["t/j"]["status"]
    assert status["phase"] == "failed"
    assert "does not hold this job's claim" in status["result"]["error"]
    assert ("t/j", "ClaimNotHeld") in world.events


def test_a_running_job_whose_cell_stopped_beating_on_the_server_fails_as_lost() -> None:
    world, _, _ = running_job_on_c0()
    world.tick((TIMING.heartbeat_timeout + TIMING.lost_grace).total_seconds() + 1)
    jobs, cells = world.snapshot()
    lagging_pass(world, jobs, cells)
    assert world.jobs["t/j"]["status"]["phase"] == "failed"
    assert ("t/j", "CellLost") in world.events

"""A Cell's ``status.queue``: the operator's summary of the queue at the cell, for the cell operator's page.

Counts and times only (a Cell is read by every tenant), written as one field
without a resourceVersion (never contending with the agent's heartbeats), when
it moved against what this replica last wrote, at most once per
``CELL_QUEUE_REFRESH``, never in a pass that claimed or released the cell.
"""

from __future__ import annotations

from datetime import timedelta

import pytest
from armnet_core.times import parse_time
from armnet_operator.model import Timing
from armnet_operator.reconcile import CELL_QUEUE_REFRESH, Limits, Memory, reconcile_once
from operator_world import World

pytestmark = pytest.mark.unit

TIMING = Timing(heartbeat_timeout=timedelta(seconds=30), claim_grace=timedelta(seconds=5))
LIMITS = Limits(position_refresh=timedelta(seconds=0))  # as the live test bed: job positions at once
REFRESH = CELL_QUEUE_REFRESH.total_seconds()


def one_pass(world: World, memory: Memory) -> None:
    jobs, cells = world.snapshot()
    reconcile_once(jobs, cells, world.now, TIMING, world, memory, LIMITS)


def queue_of(world: World, cell: str) -> dict[str, object]:
    return dict(world.cells[cell]["status"].get("queue") or {})


def a_busy_cell() -> tuple[World, Memory]:
    """One cell, holding job ``run`` (started now, a 120 s timeout, the cell's 10 s grace)."""
    world, memory = World(), Memory()
    world.add_cell("c0", "so-101", None)
    world.heartbeat("c0")
    world.submit("run", "so-101", None, 0)
    one_pass(world, memory)
    world.agent_set_phase("t/run", "running")
    world.jobs["t/run"]["status"]["startedAt"] = world.jobs["t/run"]["metadata"]["creationTimestamp"]
    return world, memory


def test_a_busy_cell_says_how_many_jobs_wait_for_it_and_when_its_job_ends_at_the_latest() -> None:
    world, memory = a_busy_cell()
    world.submit("next-1", "so-101", None, 0)
    world.submit("next-2", "so-101", None, 0)
    world.submit("elsewhere", "aloha", None, 0)  # no cell of its embodiment: not waiting for this one
    world.tick(1)
    one_pass(world, memory)
    queue = queue_of(world, "c0")
    assert queue["waitingJobs"] == 2
    started = parse_time(world.jobs["t/run"]["status"]["startedAt"])
    assert started is not None and parse_time(queue["latestFree"]) == started + timedelta(seconds=120 + 10)
    # No finished run of the embodiment yet: the likely end is the latest one.
    assert queue["likelyFree"] == queue["latestFree"]
    assert "next-1" not in str(queue)  # no tenant's job is named


def test_it_is_rewritten_when_it_moved_at_most_once_per_refresh_and_not_at_all_when_it_did_not() -> None:
    world, memory = a_busy_cell()
    world.tick(1)
    one_pass(world, memory)  # the pass after the claim writes the summary
    version = world.cells["c0"]["metadata"]["resourceVersion"]
    world.tick(REFRESH + 1)
    one_pass(world, memory)  # nothing moved: no write
    assert world.cells["c0"]["metadata"]["resourceVersion"] == version
    world.submit("next", "so-101", None, 0)
    world.tick(1)
    one_pass(world, memory)  # moved, long after the last write: written
    assert queue_of(world, "c0")["waitingJobs"] == 1
    world.submit("again", "so-101", None, 0)
    world.tick(1)
    one_pass(world, memory)  # moved 1 s after the last write: waits for the refresh
    assert queue_of(world, "c0")["waitingJobs"] == 1
    world.tick(REFRESH)
    one_pass(world, memory)
    assert queue_of(world, "c0")["waitingJobs"] == 2


def test_a_pass_that_claims_the_cell_leaves_its_summary_to_a_later_pass() -> None:
    world, memory = World(), Memory()
    world.add_cell("c0", "so-101", None)
    world.heartbeat("c0")
    world.submit("run", "so-101", None, 0)
    one_pass(world, memory)  # the claim holds the cell's resourceVersion: no other write of it
    assert world.cells["c0"]["status"]["currentJob"] == "t/run" and queue_of(world, "c0") == {}
    world.tick(1)
    one_pass(world, memory)
    assert "latestFree" in queue_of(world, "c0")


def test_what_it_wrote_is_not_written_again_while_the_watch_still_shows_the_old_summary() -> None:
    world, memory = a_busy_cell()
    world.tick(1)
    one_pass(world, memory)
    written = queue_of(world, "c0")
    assert written
    world.cells["c0"]["status"].pop("queue")  # a lagging watch: the listed Cell lacks the write
    world.tick(REFRESH + 1)
    one_pass(world, memory)
    assert queue_of(world, "c0") == {}  # not written again: nothing moved since this replica wrote it


def test_a_cell_freed_by_its_job_drops_its_free_times() -> None:
    world, memory = a_busy_cell()
    world.tick(1)
    one_pass(world, memory)
    assert "latestFree" in queue_of(world, "c0")
    world.agent_set_phase("t/run", "succeeded")
    world.tick(1)
    one_pass(world, memory)  # releases the cell: its summary waits for a later pass
    world.heartbeat("c0")
    world.tick(REFRESH)
    one_pass(world, memory)
    assert queue_of(world, "c0") == {"waitingJobs": 0}

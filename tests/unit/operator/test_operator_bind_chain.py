"""The write order of one pass for new jobs: claim, bind, then the finalizer.

Also: a claim that lost only to a heartbeat is retried once on the fresh Cell.

The finalizer of a new job is written after its bind (or just before its queue
status), never before its claim: submit->bound costs two writes. These tests
pin that order and the safety of the window it opens: a job deleted between its
claim or bind and its finalizer vanishes at once, and its cell is released
(at once, or by the repair after the claim grace) without ever holding two jobs.
"""

from __future__ import annotations

from collections import Counter
from datetime import timedelta
from typing import Any

import pytest
from armnet_core.api import ACTIVE_PHASES, RELEASE_CELL_FINALIZER
from armnet_operator.model import Timing
from armnet_operator.patches import Patch, Target
from armnet_operator.reconcile import Limits, Memory, reconcile_once
from operator_world import World

pytestmark = pytest.mark.unit

TIMING = Timing(
    heartbeat_timeout=timedelta(seconds=30),
    claim_grace=timedelta(seconds=10),
    lost_grace=timedelta(seconds=60),
    cancel_force_after=timedelta(seconds=60),
    default_ttl=timedelta(seconds=300),
)


class RecordingWorld(World):
    """The in-memory world, plus the order of the writes it received."""

    def __init__(self) -> None:
        super().__init__()
        self.writes: list[tuple[Target, str]] = []
        self.before_write: Any = None
        self.before_target: Target | None = None

    def patch(self, patch: Patch) -> dict[str, Any]:
        if self.before_write is not None and self.before_target in (None, patch.target):
            hook, self.before_write = self.before_write, None
            hook()
        self.writes.append((patch.target, patch.name))
        return super().patch(patch)


def a_world(cells: int) -> RecordingWorld:
    world = RecordingWorld()
    for i in range(cells):
        world.add_cell(f"c{i}", "so-101", None)
        world.heartbeat(f"c{i}")
    one_pass(world)  # cells get their phase
    world.writes.clear()
    return world


def one_pass(world: World, parallel: int = 1) -> None:
    jobs, cells = world.snapshot()
    reconcile_once(jobs, cells, world.now, TIMING, world, Memory(), Limits(parallel_binds=parallel))


def test_a_new_job_gets_claim_bind_and_finalizer_in_that_order_in_one_pass() -> None:
    world = a_world(cells=1)
    world.submit("j", "so-101", None, 0)
    one_pass(world)
    assert world.writes == [(Target.CELL_STATUS, "c0"), (Target.JOB_STATUS, "j"), (Target.JOB, "j")]
    job = world.jobs["t/j"]
    assert (job["status"]["phase"], job["status"]["cellName"]) == ("dispatched", "c0")
    assert job["metadata"]["finalizers"] == [RELEASE_CELL_FINALIZER]
    assert world.cells["c0"]["status"]["currentJob"] == "t/j"


def test_the_agents_status_write_does_not_make_the_finalizer_write_fail() -> None:
    world = a_world(cells=1)
    world.submit("j", "so-101", None, 0)
    world.before_target = Target.JOB
    world.before_write = lambda: world.agent_set_phase("t/j", "running")  # the agent is quicker
    one_pass(world)
    job = world.jobs["t/j"]
    assert (job["status"]["phase"], job["metadata"].get("finalizers")) == ("running", [RELEASE_CELL_FINALIZER])
    assert world.cells["c0"]["status"]["currentJob"] == "t/j"
    world.writes.clear()
    one_pass(world)
    # Nothing retried: the one write is the cell's queue summary, which the claiming pass leaves to the next.
    assert world.writes == [(Target.CELL_STATUS, "c0")] and "latestFree" in world.cells["c0"]["status"]["queue"]


def test_a_finalizer_list_that_appeared_meanwhile_is_kept_and_the_add_retried_once() -> None:
    world = a_world(cells=1)
    world.submit("j", "so-101", None, 0)

    def another_controller_adds_its_finalizer() -> None:
        world.jobs["t/j"]["metadata"]["finalizers"] = ["other.io/keep"]
        world.jobs["t/j"]["metadata"]["resourceVersion"] = world._next_rv()

    world.before_target = Target.JOB
    world.before_write = another_controller_adds_its_finalizer
    one_pass(world)
    assert world.writes == [(Target.CELL_STATUS, "c0"), (Target.JOB_STATUS, "j"), (Target.JOB, "j"), (Target.JOB, "j")]
    assert world.jobs["t/j"]["metadata"]["finalizers"] == ["other.io/keep", RELEASE_CELL_FINALIZER]


def test_a_terminal_job_without_the_finalizer_gets_none_and_still_frees_its_cell_and_expires() -> None:
    """A job that finished before its finalizer was written is being released: no finalizer write."""
    world = a_world(cells=1)
    world.submit("j", "so-101", None, 0)
    one_pass(world)
    del world.jobs["t/j"]["metadata"]["finalizers"]  # as if the agent had been quicker than the finalizer
    world.agent_set_phase("t/j", "succeeded")
    world.submit("next", "so-101", None, 0)
    world.writes.clear()
    one_pass(world)
    assert (Target.JOB, "j") not in world.writes
    assert world.jobs["t/j"]["metadata"].get("finalizers") is None
    assert world.cells["c0"]["status"]["currentJob"] == "t/next"  # released, and rebound in the same pass
    world.tick(TIMING.default_ttl.total_seconds() if TIMING.default_ttl else 0)
    world.heartbeat("c0")
    one_pass(world)
    assert "t/j" not in world.jobs  # the TTL delete needs no finalizer removal
    _check_invariant(world)


def _check_invariant(world: World) -> None:
    claims = Counter(c["status"]["currentJob"] for c in world.cells.values() if c["status"].get("currentJob"))
    assert all(n == 1 for n in claims.values()), f"a job is claimed by two cells: {claims}"
    active = [b for b in world.jobs.values() if b["status"].get("phase") in ACTIVE_PHASES]
    on_cell = Counter(b["status"]["cellName"] for b in active)
    assert all(n == 1 for n in on_cell.values()), f"two active jobs on one cell: {on_cell}"
    for body in active:
        cell = world.cells[body["status"]["cellName"]]
        assert cell["status"].get("currentJob") == f"t/{body['metadata']['name']}"


@pytest.mark.parametrize("deleted_before", [Target.CELL_STATUS, Target.JOB_STATUS, Target.JOB])
def test_a_job_deleted_inside_its_chain_frees_its_cell_and_the_next_job_gets_it(deleted_before: Target) -> None:
    """Deleted before its claim, before its bind, or between its bind and its finalizer.

    Without the finalizer the job vanishes at once. Before the claim: nothing to
    undo. Before the bind: the binder gives the claim back in the same chain.
    Between bind and finalizer: the cell names a job that no longer exists, holds
    it (no other bind) for the claim grace, then the repair releases it.
    """
    world = a_world(cells=1)
    world.submit("gone", "so-101", None, 0)
    world.before_target = deleted_before
    world.before_write = lambda: world.delete_job("t", "gone", "")
    one_pass(world)
    assert "t/gone" not in world.jobs
    _check_invariant(world)
    world.submit("next", "so-101", None, 0)
    held = world.cells["c0"]["status"].get("currentJob") == "t/gone"
    assert held == (deleted_before is Target.JOB)
    bound_after = None
    for second in range(1, int(TIMING.claim_grace.total_seconds()) + 3):
        world.tick(1)
        world.heartbeat("c0")
        one_pass(world)
        _check_invariant(world)
        if bound_after is None and world.jobs["t/next"]["status"].get("phase") == "dispatched":
            bound_after = second
    grace = int(TIMING.claim_grace.total_seconds())
    assert bound_after == (grace if held else 1)
    nxt = world.jobs["t/next"]
    assert (nxt["status"]["phase"], nxt["status"]["cellName"]) == ("dispatched", "c0")
    assert nxt["metadata"]["finalizers"] == [RELEASE_CELL_FINALIZER]
    assert world.cells["c0"]["status"]["currentJob"] == "t/next"


def test_a_job_that_waits_gets_its_queue_status_in_one_write_and_no_finalizer() -> None:
    """A waiting job holds no cell for the finalizer to protect: a burst of submissions costs one write a job."""
    world = a_world(cells=0)
    world.submit("j", "so-101", None, 0)
    one_pass(world)
    assert world.writes == [(Target.JOB_STATUS, "j")]
    job = world.jobs["t/j"]
    assert (job["status"]["phase"], job["metadata"].get("finalizers")) == ("queued", None)


def test_a_burst_binds_every_job_with_its_finalizer_in_parallel() -> None:
    world = a_world(cells=20)
    for i in range(30):
        world.submit(f"j{i:02d}", "so-101", None, 0)
    one_pass(world, parallel=8)
    bound = [b for b in world.jobs.values() if b["status"].get("phase") == "dispatched"]
    assert len(bound) == 20
    assert all(b["metadata"].get("finalizers") == [RELEASE_CELL_FINALIZER] for b in bound)
    assert not any(b["metadata"].get("finalizers") for b in world.jobs.values() if b not in bound)
    claims = [c["status"].get("currentJob") for c in world.cells.values()]
    assert sorted(claims) == sorted(f"t/{b['metadata']['name']}" for b in bound)


def test_a_claim_that_lost_to_a_heartbeat_is_retried_on_the_fresh_cell() -> None:
    world = a_world(cells=1)
    world.submit("j", "so-101", None, 0)
    world.before_target = Target.CELL_STATUS
    world.before_write = lambda: world.heartbeat("c0")  # the agent writes between our read and claim
    one_pass(world)
    assert world.jobs["t/j"]["status"]["phase"] == "dispatched"
    assert world.cells["c0"]["status"]["currentJob"] == "t/j"


def test_a_claim_that_lost_to_another_claim_is_not_retried() -> None:
    world = a_world(cells=1)
    world.submit("j", "so-101", None, 0)
    world.submit("other", "so-101", None, 0)
    world.jobs["t/other"]["metadata"]["finalizers"] = [RELEASE_CELL_FINALIZER]

    def someone_else_claims() -> None:
        cell = world.cells["c0"]
        cell["status"]["currentJob"] = "t/other"
        cell["metadata"]["resourceVersion"] = world._next_rv()

    jobs, cells = world.snapshot()
    jobs = [j for j in jobs if j.name == "j"]  # this writer does not see the other job yet
    world.before_target = Target.CELL_STATUS
    world.before_write = someone_else_claims
    reconcile_once(jobs, cells, world.now, TIMING, world, Memory(), Limits())
    assert world.cells["c0"]["status"]["currentJob"] == "t/other"
    assert world.jobs["t/j"]["status"].get("phase") != "dispatched"


def test_a_burst_of_new_jobs_is_queued_over_several_short_passes_with_the_head_of_the_queue_first() -> None:
    world = RecordingWorld()
    world.add_cell("c1", "so-101", None)
    world.heartbeat("c1")
    for i in range(10):
        world.submit(f"j{i}", "so-101", None, 0)
    limits = Limits(max_queue_tasks=4)
    first = reconcile_once(*world.snapshot(), world.now, TIMING, world, Memory(), limits)
    assert first.more and [j.name for j, _ in first.bound] == ["j0"]
    queued = sorted(k for k, b in world.jobs.items() if b["status"].get("phase") == "queued")
    assert queued == ["t/j1", "t/j2", "t/j3"]  # j0's finalizer took the fourth slot
    memory = Memory()
    while reconcile_once(*world.snapshot(), world.now, TIMING, world, memory, limits).more:
        pass
    assert all(b["status"].get("phase") in ("queued", "dispatched") for b in world.jobs.values())


def test_queue_writes_past_the_pass_budget_are_left_for_the_next_pass() -> None:
    world = RecordingWorld()
    world.add_cell("c1", "so-101", None)
    world.heartbeat("c1")
    for i in range(5):
        world.submit(f"j{i}", "so-101", None, 0)
    outcome = reconcile_once(*world.snapshot(), world.now, TIMING, world, Memory(), Limits(queue_seconds=-1))
    assert outcome.more and [j.name for j, _ in outcome.bound] == ["j0"]
    assert not any(b["status"].get("phase") == "queued" for b in world.jobs.values())

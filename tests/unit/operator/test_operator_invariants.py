"""Property: whatever happens, never two active jobs on one cell, never one job on two cells.

Hypothesis drives random interleavings of submit, cancel, delete, cell up/down,
agent start/finish, time passing, operator crashes mid-pass, restarts, and a
second replica acting on a stale snapshot (its job and cell watches lagging by
different amounts), through the real reconcile code. Some jobs ask for a pre-flight,
which runs on the one simulated twin: no ordinary job ever holds the twin, no
pre-flight a real cell, and a job holds a real cell only after its pre-flight passed.
"""

from __future__ import annotations

from collections import Counter
from datetime import timedelta

import pytest
from armnet_core.api import ACTIVE_PHASES, PREFLIGHT_FOR_ANNOTATION, TERMINAL_PHASES
from armnet_operator.model import Timing
from armnet_operator.reconcile import Memory, reconcile_once
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, initialize, invariant, rule
from operator_world import Crash, World

pytestmark = pytest.mark.unit

TIMING = Timing(
    heartbeat_timeout=timedelta(seconds=30),
    claim_grace=timedelta(seconds=10),
    lost_grace=timedelta(seconds=60),
    cancel_force_after=timedelta(seconds=60),
    default_ttl=timedelta(seconds=300),
)
EMBODIMENTS = ["so-101", "bimanual"]
TASKS = [None, "fold", "stack"]
CELLS = [(f"c{i}", EMBODIMENTS[i % 2], TASKS[i % 3]) for i in range(4)]
#: A simulated twin for pre-flights only (``spec.preflight``).
TWIN = "twin-0"


class Cluster(RuleBasedStateMachine):
    @initialize()
    def start(self) -> None:
        self.world = World()
        self.memory = Memory()
        self.up = {name: True for name, _, _ in CELLS}
        self.count = 0
        self.started: set[str] = set()
        for name, embodiment, task in CELLS:
            self.world.add_cell(name, embodiment, task)
            self.world.heartbeat(name)
        self.world.add_cell(TWIN, EMBODIMENTS[0], None, simulated=True, preflight=True)
        self.world.heartbeat(TWIN)
        self.up[TWIN] = True

    def _pick(self, index: int) -> str | None:
        keys = sorted(self.world.jobs)
        return keys[index % len(keys)] if keys else None

    @rule(embodiment=st.sampled_from(EMBODIMENTS), task=st.sampled_from(TASKS), priority=st.integers(0, 3))
    def submit(self, embodiment: str, task: str | None, priority: int) -> None:
        self.count += 1
        self.world.submit(f"j{self.count}", embodiment, task, priority)

    @rule(task=st.sampled_from(TASKS), priority=st.integers(0, 3))
    def submit_with_preflight(self, task: str | None, priority: int) -> None:
        self.count += 1
        self.world.submit(f"j{self.count}", EMBODIMENTS[0], task, priority, preflight={"seconds": 30})

    @rule(index=st.integers(0, 100))
    def cancel(self, index: int) -> None:
        key = self._pick(index)
        if key:
            self.world.user_patch_job(key, {"cancel": True})

    @rule(index=st.integers(0, 100))
    def delete(self, index: int) -> None:
        key = self._pick(index)
        if key:
            namespace, name = key.split("/")
            self.world.delete_job(namespace, name, "")

    @rule(cell=st.sampled_from([c[0] for c in CELLS] + [TWIN]), up=st.booleans())
    def cell_up_or_down(self, cell: str, up: bool) -> None:
        self.up[cell] = up

    @rule(seconds=st.sampled_from([1, 5, 11, 31, 65, 120]))
    def time_passes(self, seconds: int) -> None:
        self.world.tick(seconds)
        for name, alive in self.up.items():
            if alive:
                self.world.heartbeat(name)

    @rule(finish=st.sampled_from(["succeeded", "failed", "cancelled"]))
    def agents_work(self, finish: str) -> None:
        """Each live agent starts its dispatched job, or ends its running one."""
        for name, alive in self.up.items():
            if not alive:
                continue
            claim = self.world.cells[name]["status"].get("currentJob")
            body = self.world.jobs.get(claim or "")
            if body is None or body["status"].get("cellName") != name:
                continue
            phase = body["status"].get("phase")
            if phase == "dispatched":
                self.world.agent_set_phase(claim, "running")
            elif phase == "running":
                cancel = body["spec"].get("cancel") or body["metadata"].get("deletionTimestamp")
                self.world.agent_set_phase(claim, "cancelled" if cancel else finish)

    @rule()
    def operator_reconciles(self) -> None:
        jobs, cells = self.world.snapshot()
        reconcile_once(jobs, cells, self.world.now, TIMING, self.world, self.memory)

    @rule(after=st.integers(0, 6))
    def operator_crashes_mid_pass_and_restarts(self, after: int) -> None:
        jobs, cells = self.world.snapshot()
        self.world.crash_after = after
        try:
            reconcile_once(jobs, cells, self.world.now, TIMING, self.world, self.memory)
        except Crash:
            pass
        finally:
            self.world.crash_after = None
        self.memory = Memory()

    @rule()
    def second_replica_observes(self) -> None:
        """Replica B's cache: it may act on it much later, after anything else happened."""
        self.stale = self.world.snapshot()

    @rule()
    def second_replica_sees_cells_catch_up(self) -> None:
        """Its Cell watch catches up while its RobotJob watch still lags (separate streams)."""
        if getattr(self, "stale", None) is not None:
            self.stale = (self.stale[0], self.world.snapshot()[1])

    @rule()
    def second_replica_acts_on_its_stale_cache(self) -> None:
        if getattr(self, "stale", None) is not None:
            jobs, cells = self.stale
            reconcile_once(jobs, cells, self.world.now, TIMING, self.world, Memory())

    @invariant()
    def never_two_active_jobs_on_one_cell_nor_one_job_on_two_cells(self) -> None:
        if not hasattr(self, "world"):
            return
        claims = Counter(
            c["status"]["currentJob"] for c in self.world.cells.values() if c["status"].get("currentJob")
        )
        assert all(n == 1 for n in claims.values()), f"a job is claimed by two cells: {claims}"
        active = [b for b in self.world.jobs.values() if b["status"].get("phase") in ACTIVE_PHASES]
        on_cell = Counter(b["status"]["cellName"] for b in active)
        assert all(n == 1 for n in on_cell.values()), f"two active jobs on one cell: {on_cell}"
        for body in active:
            key = f"t/{body['metadata']['name']}"
            cell = self.world.cells[body["status"]["cellName"]]
            assert cell["status"].get("currentJob") == key, f"{key} active on an unclaimed cell"

    @invariant()
    def twins_hold_only_preflights_and_a_job_holds_a_real_cell_only_after_its_preflight_passed(self) -> None:
        if not hasattr(self, "world"):
            return
        owners: Counter[str] = Counter()
        for key, body in self.world.jobs.items():
            annotations = body["metadata"].get("annotations") or {}
            is_preflight = PREFLIGHT_FOR_ANNOTATION in annotations
            if is_preflight:
                owners[annotations[PREFLIGHT_FOR_ANNOTATION]] += 1
            status = body["status"]
            if status.get("phase") not in ACTIVE_PHASES:
                continue
            assert (status["cellName"] == TWIN) == is_preflight, f"{key} ({status}) holds the wrong kind of cell"
            if body["spec"].get("preflight") and not is_preflight:
                assert (status.get("preflight") or {}).get("phase") == "Passed", f"{key} bound before its pre-flight passed"
        assert all(n == 1 for n in owners.values()), f"a job has more than one pre-flight: {owners}"
        for name, cell in self.world.cells.items():
            holder = self.world.jobs.get(cell["status"].get("currentJob") or "")
            if holder is not None:
                annotations = holder["metadata"].get("annotations") or {}
                assert (name == TWIN) == (PREFLIGHT_FOR_ANNOTATION in annotations), f"cell {name} claimed by {holder}"

    @invariant()
    def a_queued_job_names_no_cell_and_a_started_job_never_goes_back(self) -> None:
        """A stale writer must not move a job backwards (e.g. a bound job back into the queue)."""
        if not hasattr(self, "world"):
            return
        for key, body in self.world.jobs.items():
            phase = body["status"].get("phase")
            if phase == "queued":
                assert not body["status"].get("cellName"), f"{key} is queued but names cell {body['status']['cellName']}"
            if phase == "running":
                self.started.add(key)
            elif key in self.started:
                assert phase in TERMINAL_PHASES, f"{key} went from running to {phase}"


TestClusterInvariants = Cluster.TestCase
TestClusterInvariants.settings = settings(
    max_examples=250, stateful_step_count=40, deadline=None,
    suppress_health_check=[HealthCheck.too_slow],
)


def test_the_queue_drains_when_agents_keep_working() -> None:
    """Liveness companion to the property: with healthy cells every job eventually ends."""
    world, memory = World(), Memory()
    for name, embodiment, _ in CELLS:
        world.add_cell(name, embodiment, None)
    for i in range(12):
        world.submit(f"j{i}", EMBODIMENTS[i % 2], None, i % 3)
    for _ in range(200):
        for name, _, _ in CELLS:
            world.heartbeat(name)
        jobs, cells = world.snapshot()
        reconcile_once(jobs, cells, world.now, TIMING, world, memory)
        for name, _, _ in CELLS:
            claim = world.cells[name]["status"].get("currentJob")
            body = world.jobs.get(claim or "")
            if body and body["status"].get("phase") == "dispatched":
                world.agent_set_phase(claim, "running")
            elif body and body["status"].get("phase") == "running":
                world.agent_set_phase(claim, "succeeded")
        world.tick(1)
    phases = Counter(b["status"].get("phase") for b in world.jobs.values())
    assert phases == {"succeeded": 12}
    assert ("t/j0", "Bound") in world.events

"""One bad object never stops scheduling.

A pass that fails on one object reports it (log with its name, Event,
``Reconciled`` condition, metric), skips it and whatever is tied to it, and
binds the rest. The reconcile loop outlives every error; if its task ends
anyway, the operator is told to exit instead of idling in the Lease.
"""

from __future__ import annotations

import asyncio
from dataclasses import replace
from datetime import timedelta
from typing import Any

import pytest
from armnet_operator.controller import Controller
from armnet_operator.metrics import Metrics
from armnet_operator.model import JobPhase, Timing
from armnet_operator.patches import Patch
from armnet_operator.reconcile import Memory, reconcile_once, screen
from armnet_operator.settings import load_settings
from operator_builders import NOW, TIMING, a_cell, a_job
from operator_world import World

pytestmark = pytest.mark.unit

WORLD_TIMING = Timing(heartbeat_timeout=timedelta(seconds=30), claim_grace=timedelta(seconds=10))


def two_cells_three_jobs(world: World) -> None:
    for cell in ("c1", "c2"):
        world.add_cell(cell, "so-101", None)
        world.heartbeat(cell)
    for name in ("good-1", "bad", "good-2"):
        world.submit(name, "so-101", None, 0)


def conditions(world: World, key: str) -> dict[str, dict[str, Any]]:
    return {c["type"]: c for c in world.jobs[key]["status"].get("conditions", [])}


def test_a_job_the_decisions_fail_on_is_skipped_and_the_rest_are_bound(caplog: pytest.LogCaptureFixture) -> None:
    world = World()
    two_cells_three_jobs(world)
    jobs, cells = world.snapshot()
    # A finished time the lifecycle cannot compare with now (no time zone): TypeError on this job only.
    jobs = [replace(j, phase=JobPhase.SUCCEEDED, finished_at=NOW.replace(tzinfo=None)) if j.name == "bad" else j
            for j in jobs]
    outcome = reconcile_once(jobs, cells, world.now, WORLD_TIMING, world, Memory())
    assert sorted(job.name for job, _ in outcome.bound) == ["good-1", "good-2"]
    assert list(outcome.failed) == ["job:t/bad"] and "TypeError" in outcome.failed["job:t/bad"].error
    assert ("t/bad", "ReconcileFailed") in world.events
    assert conditions(world, "t/bad")["Reconciled"]["status"] == "False"
    assert "RobotJob t/bad failed" in caplog.text


class FailingWorld(World):
    """The API answers one job's writes with something no error type expects."""

    def patch(self, patch: Patch) -> dict[str, Any]:
        if patch.name == "bad" and "Reconciled" not in str(patch.body):
            raise RuntimeError("unexpected response")
        return super().patch(patch)


def test_a_job_whose_writes_fail_unexpectedly_is_reported_once_and_the_rest_are_bound() -> None:
    world = FailingWorld()
    two_cells_three_jobs(world)
    world.add_cell("c3", "so-101", None)
    world.heartbeat("c3")
    memory = Memory()
    first = reconcile_once(*world.snapshot(), world.now, WORLD_TIMING, world, memory)
    assert sorted(job.name for job, _ in first.bound) == ["good-1", "good-2"]
    assert "RuntimeError: unexpected response" in first.failed["job:t/bad"].error
    reconcile_once(*world.snapshot(), world.now, WORLD_TIMING, world, memory)
    assert world.events.count(("t/bad", "ReconcileFailed")) == 1


def test_a_job_that_recovers_gets_its_reconciled_condition_back() -> None:
    world = World()
    two_cells_three_jobs(world)
    memory = Memory(failing={"job:t/bad": "TypeError: earlier"})
    reconcile_once(*world.snapshot(), world.now, WORLD_TIMING, world, memory)
    assert conditions(world, "t/bad")["Reconciled"]["status"] == "True"
    assert memory.failing == {}


def test_a_cell_tied_to_a_skipped_job_is_skipped_too_so_its_claim_is_not_released() -> None:
    bad = replace(a_job().running_on("c"), finished_at=NOW.replace(tzinfo=None), phase=JobPhase.SUCCEEDED)
    cell = a_cell().named("c").claimed_by(bad).ready()
    other = a_cell().named("other").ready()
    jobs, cells, failed = screen([bad], [cell, other], NOW, TIMING)
    assert (jobs, [c.name for c in cells], list(failed)) == ([], ["other"], [f"job:{bad.key}"])


def test_the_loop_outlives_an_error_of_any_type() -> None:
    settings = load_settings({"reconcile_period": 0.01, "metrics_port": 0}, environ={})
    controller = Controller(settings, api=None, metrics=Metrics())  # type: ignore[arg-type]
    calls: list[int] = []

    def reconcile() -> None:
        calls.append(1)
        if len(calls) == 1:
            raise OverflowError("date value out of range")

    controller.reconcile = reconcile  # type: ignore[method-assign]

    async def run() -> None:
        controller.start()
        while len(calls) < 3:
            await asyncio.sleep(0.01)
        await controller.stop()

    asyncio.run(asyncio.wait_for(run(), 10))
    assert not controller.dead
    assert controller.metrics.errors._value.get() == 1


def test_a_loop_that_ends_by_itself_asks_the_process_to_exit() -> None:
    settings = load_settings({"reconcile_period": 0.01, "metrics_port": 0}, environ={})
    deaths: list[BaseException | None] = []
    controller = Controller(settings, api=None, metrics=Metrics(), on_death=deaths.append)  # type: ignore[arg-type]
    controller.reconcile = lambda: None  # type: ignore[method-assign]

    async def run() -> None:
        controller.start()
        await asyncio.sleep(0.05)
        assert controller._task is not None
        controller._task.cancel()  # not through stop(): the task ends under the operator
        await asyncio.sleep(0.05)

    asyncio.run(run())
    assert controller.dead and deaths == [None]


def test_stopping_the_operator_is_not_a_death() -> None:
    settings = load_settings({"reconcile_period": 0.01, "metrics_port": 0}, environ={})
    deaths: list[BaseException | None] = []
    controller = Controller(settings, api=None, metrics=Metrics(), on_death=deaths.append)  # type: ignore[arg-type]
    controller.reconcile = lambda: None  # type: ignore[method-assign]

    async def run() -> None:
        controller.start()
        await asyncio.sleep(0.03)
        await controller.stop()

    asyncio.run(run())
    assert not controller.dead and deaths == []

"""A cell's duty cycle: it rests R minutes every H hours, never in the middle of a job.

The pure rule (``duty_cycle``) as a table, then the reconcile pass on the in-memory
API server: a cell whose working time is up finishes its job, rests (no job is bound,
phase ``Resting``, an Event), then takes the waiting job once the rest is over.
"""

from __future__ import annotations

from dataclasses import replace
from datetime import timedelta

import pytest
from armnet_operator.duty_cycle import (
    NO_STATE,
    DutyCycle,
    DutyState,
    next_state,
    ready_at,
    rest_due,
)
from armnet_operator.estimate import queue_starts, seats
from armnet_operator.health import derive_cell_phase
from armnet_operator.model import CellPhase
from armnet_operator.reconcile import Limits, Memory, reconcile_once
from operator_builders import NOW, TIMING, a_cell, a_job

from tests.unit.operator.operator_world import World

pytestmark = pytest.mark.unit

CYCLE = DutyCycle(rest=timedelta(minutes=20), every=timedelta(hours=6))
H = timedelta(hours=1)


@pytest.mark.parametrize(("state", "occupied", "expected"), [
    pytest.param(NO_STATE, False, DutyState(NOW), id="a cycle begins when first seen"),
    pytest.param(DutyState(NOW - 5 * H), False, DutyState(NOW - 5 * H), id="working"),
    pytest.param(DutyState(NOW - 6 * H), False, DutyState(NOW - 6 * H, NOW + timedelta(minutes=20)),
                 id="time is up and the cell is free: it rests"),
    pytest.param(DutyState(NOW - 7 * H), True, DutyState(NOW - 7 * H), id="never in the middle of a job"),
    pytest.param(DutyState(NOW - 7 * H, NOW + H), False, DutyState(NOW - 7 * H, NOW + H), id="resting"),
    pytest.param(DutyState(NOW - 7 * H, NOW), False, DutyState(NOW), id="the rest is over: working again"),
])
def test_next_state(state: DutyState, occupied: bool, expected: DutyState) -> None:
    assert next_state(CYCLE, state, occupied, NOW) == expected


M = timedelta(minutes=1)


@pytest.mark.parametrize(("state", "free_at", "ready", "after"), [
    pytest.param(DutyState(NOW - 5 * H), NOW + 30 * M, NOW + 30 * M, DutyState(NOW - 5 * H),
                 id="working time left when free: at once"),
    pytest.param(DutyState(NOW - 5 * H), NOW + 2 * H, NOW + 2 * H + 20 * M, DutyState(NOW + 2 * H + 20 * M),
                 id="time up by then: after a rest that begins then"),
    pytest.param(DutyState(NOW - 7 * H, NOW + 10 * M), NOW, NOW + 10 * M, DutyState(NOW + 10 * M),
                 id="resting: at the rest's end"),
    pytest.param(DutyState(NOW - 7 * H, NOW + 10 * M), NOW + H, NOW + H, DutyState(NOW + 10 * M),
                 id="free after the rest: at once, in the next working time"),
    pytest.param(NO_STATE, NOW + 7 * H, NOW + 7 * H + 20 * M, DutyState(NOW + 7 * H + 20 * M),
                 id="no cycle recorded yet: it begins now"),
])
def test_when_a_cell_can_start_its_next_job(state: DutyState, free_at, ready, after) -> None:  # noqa: ANN001
    assert ready_at(CYCLE, state, free_at, NOW) == (ready, after)
    assert ready_at(None, state, free_at, NOW) == (free_at, state)


def test_the_start_estimates_count_the_rests_a_cell_takes_on_the_way() -> None:
    cell = replace(a_cell().named("c1").with_grace(0).build(), duty_cycle=CYCLE, duty=DutyState(NOW - 5 * H))
    running = a_job().named("run").with_timeout(3600).started_ago(1800).running_on("c1")
    first, second = (a_job().named(n).with_timeout(3600).queued() for n in ("first", "second"))
    starts = queue_starts([first, second], seats([cell], {"c1": running}, NOW))
    # run ends at +30 min (working time left: first starts then); first ends at +90 min, past the
    # 6 hours: the cell rests 20 minutes before second.
    assert starts == {first.key: NOW + 30 * M, second.key: NOW + 110 * M}
    resting = replace(cell, duty=DutyState(NOW - 7 * H, NOW + 15 * M))
    assert queue_starts([first], seats([resting], {}, NOW)) == {first.key: NOW + 15 * M}


def test_without_a_cycle_nothing_is_recorded_and_nothing_rests() -> None:
    assert next_state(None, DutyState(NOW - 7 * H, NOW + H), False, NOW) == NO_STATE
    assert not rest_due(None, DutyState(NOW - 7 * H, NOW + H), NOW)


def test_a_cell_whose_time_is_up_takes_no_new_job_but_keeps_the_one_it_runs() -> None:
    cell = a_cell().named("c1").ready()
    due = replace(cell, duty_cycle=CYCLE, duty=DutyState(NOW - 6 * H))
    assert derive_cell_phase(due, False, NOW, TIMING.heartbeat_timeout) is CellPhase.RESTING
    assert derive_cell_phase(due, True, NOW, TIMING.heartbeat_timeout) is CellPhase.BUSY
    cordoned = replace(due, unschedulable=True)
    assert derive_cell_phase(cordoned, False, NOW, TIMING.heartbeat_timeout) is CellPhase.CORDONED


def run(world: World, memory: Memory) -> None:
    for cell in world.cells:
        world.heartbeat(cell)
    jobs, cells = world.snapshot()
    reconcile_once(jobs, cells, world.now, TIMING, world, memory, Limits())


def test_the_cell_rests_after_its_job_and_takes_the_waiting_job_once_rested() -> None:
    world, memory = World(), Memory()
    world.add_cell("c1", "so101", None)
    world.cells["c1"]["spec"]["dutyCycle"] = {"restMinutes": 20, "everyHours": 1}
    world.submit("first", "so101", None, 0)
    run(world, memory)
    assert world.jobs["t/first"]["status"]["phase"] == "dispatched"
    since = world.cells["c1"]["status"]["dutyCycle"]["workingSince"]
    world.agent_set_phase("t/first", "running")
    world.tick(3600)  # the working time is up while the job runs: it goes on
    world.submit("second", "so101", None, 0)
    run(world, memory)
    assert world.cells["c1"]["status"]["phase"] == "Busy"
    assert world.cells["c1"]["status"]["dutyCycle"] == {"workingSince": since}
    world.tick(60)
    world.agent_set_phase("t/first", "succeeded")
    run(world, memory)
    status = world.cells["c1"]["status"]
    assert status["phase"] == "Resting" and "restingUntil" in status["dutyCycle"]
    assert world.jobs["t/second"]["status"]["phase"] == "queued"
    assert ("c1", "Resting") in world.events
    world.tick(19 * 60)
    run(world, memory)
    assert world.jobs["t/second"]["status"]["phase"] == "queued"
    world.tick(60)
    run(world, memory)
    run(world, memory)
    assert world.jobs["t/second"]["status"]["phase"] == "dispatched"
    assert "restingUntil" not in world.cells["c1"]["status"]["dutyCycle"]


def test_removing_the_duty_cycle_clears_its_record() -> None:
    world, memory = World(), Memory()
    world.add_cell("c1", "so101", None)
    world.cells["c1"]["spec"]["dutyCycle"] = {"restMinutes": 20, "everyHours": 1}
    run(world, memory)
    assert "dutyCycle" in world.cells["c1"]["status"]
    del world.cells["c1"]["spec"]["dutyCycle"]
    run(world, memory)
    assert "dutyCycle" not in world.cells["c1"]["status"]

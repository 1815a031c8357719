"""A cell's duty cycle: rest R minutes every H hours, never in the middle of a job. Pure.

Robots that run around the clock wear and heat up; AutoEval rests its arms 20
minutes every 6 hours. A Cell's ``spec.dutyCycle`` asks for the same: once
``everyHours`` have passed since the cell's working time began, the cell takes no
new job; when the job it runs ends (a running job is never interrupted) it rests
``restMinutes`` (phase ``Resting``), then works again. The state lives in the
Cell's ``status.dutyCycle`` (``workingSince``, ``restingUntil``), written by the
operator, so a restart or a new leader continues the same cycle.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime, timedelta


@dataclass(frozen=True)
class DutyCycle:
    rest: timedelta
    every: timedelta


@dataclass(frozen=True)
class DutyState:
    """``status.dutyCycle`` as written; both None: no cycle recorded."""

    working_since: datetime | None = None
    resting_until: datetime | None = None


NO_STATE = DutyState()


def resting(state: DutyState, now: datetime) -> bool:
    """Inside a rest the operator recorded."""
    return state.resting_until is not None and now < state.resting_until


def rest_due(cycle: DutyCycle | None, state: DutyState, now: datetime) -> bool:
    """The cell must take no new job: it rests now, or its working time is up (it rests once free)."""
    if cycle is None:
        return False
    if resting(state, now):
        return True
    return state.resting_until is None and state.working_since is not None and now - state.working_since >= cycle.every


def next_state(cycle: DutyCycle | None, state: DutyState, occupied: bool, now: datetime) -> DutyState:
    """The state to record now: a cycle begins when first seen, a rest when the working time is up
    and the cell is free, the next working time when the rest is over; none without a cycle."""
    if cycle is None:
        return NO_STATE
    if state.resting_until is not None:
        return state if now < state.resting_until else DutyState(working_since=now)
    if state.working_since is None:
        return DutyState(working_since=now)
    if now - state.working_since >= cycle.every and not occupied:
        return DutyState(working_since=state.working_since, resting_until=now + cycle.rest)
    return state


def ready_at(cycle: DutyCycle | None, state: DutyState, free_at: datetime, now: datetime) -> tuple[datetime, DutyState]:
    """When a cell that is free from ``free_at`` on can start a job, and its cycle from then on.

    For the start estimates (``estimate``), which walk the queue ahead: inside a rest, at
    its end; once the working time is up at ``free_at``, after the rest that begins then;
    else at once. A cycle not recorded yet begins ``now`` (the operator records it in this pass).
    """
    if cycle is None:
        return free_at, state
    if state.resting_until is not None:
        if free_at < state.resting_until:
            return state.resting_until, DutyState(working_since=state.resting_until)
        state = DutyState(working_since=state.resting_until)
    working_since = state.working_since or now
    if free_at - working_since >= cycle.every:
        back = free_at + cycle.rest
        return back, DutyState(working_since=back)
    return free_at, DutyState(working_since=working_since)


__all__ = ["NO_STATE", "DutyCycle", "DutyState", "next_state", "ready_at", "rest_due", "resting"]

"""Pure safety decisions over plain data: is this goal-position write allowed?

This module owns the rules (LeRobot ``max_relative_target`` semantics for the
step from the present position, and the calibrated absolute range of each
motor). It never touches a bus: the caller reads the present positions and
passes them in, so every rule is testable with plain dicts.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from .config import MotorRange

GOAL_POSITION = "Goal_Position"
#: Registers that may still be written while the interlock holds, and only with 0
#: (what ``disable_torque`` writes): letting go of the arm is always allowed. Not
#: ``Lock``: 0 unlocks the EEPROM (the connector's bus never writes it, see ``policed_bus``).
RELEASE_REGISTERS = frozenset({"Torque_Enable"})
#: Registers a job may never write: they re-address servos of a shared cell (as
#: ``setup_motor``/``set_baudrate`` would), leaving the next job a broken bus.
PROTECTED_REGISTERS = frozenset({"ID", "Baud_Rate"})

DEGREES = "degrees"
RANGE_0_100 = "range_0_100"
RANGE_M100_100 = "range_m100_100"
_MAX_RES = 4095


@dataclass(frozen=True)
class Violation:
    """Why a goal write was refused: which motor, how far it asked to move, and the limit."""

    motor: str
    kind: str  # "relative" | "absolute"
    requested: float
    limit: float
    present: float | None = None
    step: float | None = None
    bounds: tuple[float, float] | None = None

    def message(self) -> str:
        if self.kind == "relative":
            return (
                f"safety limit: motor {self.motor!r} was asked to move {self.step:+.3f} "
                f"(from {self.present:.3f} to {self.requested:.3f}) but the cell allows at most "
                f"{self.limit:.3f} per write; the write was refused and the cell's interlock tripped. "
                "Send smaller steps (LeRobot max_relative_target) toward far goals."
            )
        low, high = self.bounds or (math.nan, math.nan)
        return (
            f"safety limit: motor {self.motor!r} goal {self.requested:.3f} is outside its calibrated "
            f"range [{low:.3f}, {high:.3f}] (raw servo ticks); the write was refused and the cell's "
            "interlock tripped. Keep goals inside the calibrated range."
        )


def is_release_write(data_name: str, values: Mapping[str, float]) -> bool:
    """True for writes that only let go of the arm (torque off / unlock), allowed under the interlock."""
    return data_name in RELEASE_REGISTERS and all(v == 0 for v in values.values())


def limit_for(limit: float | Mapping[str, float] | None, motor: str) -> float | None:
    """The relative limit of one motor (a number for all, or a per-motor mapping)."""
    if limit is None:
        return None
    if isinstance(limit, Mapping):
        value = limit.get(motor)
        return None if value is None else float(value)
    return float(limit)


def ticks_per_unit(norm_mode: str, motor_range: MotorRange) -> float:
    """How many raw ticks one normalised unit spans, to express a limit on a raw write."""
    span = motor_range.range_max - motor_range.range_min
    if norm_mode == DEGREES:
        return _MAX_RES / 360.0
    if norm_mode == RANGE_0_100:
        return span / 100.0
    return span / 200.0


def to_raw(value: float, norm_mode: str, motor_range: MotorRange, *, apply_drive_mode: bool = True) -> int:
    """LeRobot's ``_unnormalize`` for one value (STS3215 resolution), as raw servo ticks."""
    low, high = motor_range.range_min, motor_range.range_max
    drive = apply_drive_mode and bool(motor_range.drive_mode)
    if norm_mode == DEGREES:
        return int(value * _MAX_RES / 360 + (low + high) / 2)
    if norm_mode == RANGE_0_100:
        v = 100 - value if drive else value
        v = min(100.0, max(0.0, v))
        return int((v / 100) * (high - low) + low)
    v = -value if drive else value
    v = min(100.0, max(-100.0, v))
    return int(((v + 100) / 200) * (high - low) + low)


@dataclass(frozen=True)
class MotorFacts:
    """What the checker knows about one motor of the bus being written."""

    norm_mode: str
    bus_range: MotorRange | None  # the calibration the bus normalises with (may be the customer's)
    cell_range: MotorRange | None  # the cell's own calibration: the absolute limits
    #: The unit the cell's limit is in (the cell's norm mode); None: the bus's own unit.
    limit_norm_mode: str | None = None


def limit_in_write_units(limit: float, fact: MotorFacts, *, normalize: bool) -> float:
    """The cell's relative limit expressed in the units of a write, through raw ticks."""
    scale_range = fact.cell_range or fact.bus_range
    if scale_range is None:
        return limit
    ticks = limit * ticks_per_unit(fact.limit_norm_mode or fact.norm_mode, scale_range)
    if not normalize:
        return ticks
    per_unit = ticks_per_unit(fact.norm_mode, scale_range)
    return ticks / per_unit if per_unit > 0 else limit


def check_goal_write(
    goals: Mapping[str, float],
    present: Mapping[str, float],
    facts: Mapping[str, MotorFacts],
    limit: float | Mapping[str, float] | None,
    *,
    normalize: bool,
) -> Violation | None:
    """The first violation among ``goals`` (in the write's units), or ``None`` if all are safe.

    The relative rule compares each goal with the present position read in the
    same units; a raw write has its limit converted to ticks. The absolute rule
    converts the goal to raw ticks with the calibration the bus itself uses and
    checks it against the cell's calibrated range, so a customer calibration
    cannot widen the range.
    """
    for motor, goal in goals.items():
        fact = facts.get(motor)
        if fact is None:
            continue  # not a motor of this bus: the real call refuses it
        if fact.cell_range is not None and (fact.bus_range is not None or not normalize):
            # (normalised without a bus calibration: the real call fails on its own)
            raw = to_raw(goal, fact.norm_mode, fact.bus_range) if fact.bus_range and normalize else int(goal)
            low, high = fact.cell_range.range_min, fact.cell_range.range_max
            if not low <= raw <= high:
                return Violation(motor, "absolute", float(raw), float(high), bounds=(low, high))
        rel = limit_for(limit, motor)
        if rel is not None and motor in present:
            rel = limit_in_write_units(rel, fact, normalize=normalize)
            step = goal - present[motor]
            if abs(step) > rel:
                return Violation(motor, "relative", goal, rel, present=present[motor], step=step)
    return None


@dataclass(frozen=True)
class GoalDecision:
    """What becomes of one goal write: the goals to send, which were clamped, and the steps asked."""

    goals: dict[str, float]
    clamped: tuple[str, ...] = ()
    #: Step from the present position per motor, as requested (before any clamp).
    steps: dict[str, float] | None = None
    violation: Violation | None = None


def decide_goal_write(
    goals: Mapping[str, float],
    present: Mapping[str, float],
    facts: Mapping[str, MotorFacts],
    limit: float | Mapping[str, float] | None,
    *,
    normalize: bool,
    clamp: bool,
) -> GoalDecision:
    """The ``clamp``/``trip`` safety policy over one goal write.

    A goal outside the calibrated range is always a violation. A step beyond the
    relative limit is a violation under ``trip``; under ``clamp`` the goal is moved
    to present ± limit, as LeRobot's ``ensure_safe_goal_position`` does.
    """
    steps = {m: goals[m] - present[m] for m in goals if m in present}
    if not clamp:
        return GoalDecision(dict(goals), (), steps, check_goal_write(goals, present, facts, limit, normalize=normalize))
    absolute = check_goal_write(goals, {}, facts, None, normalize=normalize)
    if absolute is not None:
        return GoalDecision(dict(goals), (), steps, absolute)
    result = dict(goals)
    clamped = []
    for motor, step in steps.items():
        fact = facts.get(motor)
        rel = limit_for(limit, motor)
        if fact is None or rel is None:
            continue
        rel = limit_in_write_units(rel, fact, normalize=normalize)
        if abs(step) > rel:
            # A raw goal stays whole ticks, inside the limit.
            allowed = rel if normalize else float(math.floor(rel))
            result[motor] = present[motor] + math.copysign(allowed, step)
            clamped.append(motor)
    return GoalDecision(result, tuple(clamped), steps, None)


def plan_rest_steps(
    present: Mapping[str, int], target: Mapping[str, int], max_step: float
) -> list[dict[str, int]]:
    """Goal dicts (raw ticks) that walk every motor from ``present`` to ``target``, each step ≤ ``max_step``."""
    motors = [m for m in target if m in present]
    if not motors:
        return []
    distance = max(abs(target[m] - present[m]) for m in motors)
    count = max(1, math.ceil(distance / max_step)) if max_step > 0 else 1
    steps = []
    for i in range(1, count + 1):
        frac = i / count
        steps.append({m: int(round(present[m] + (target[m] - present[m]) * frac)) for m in motors})
    return steps

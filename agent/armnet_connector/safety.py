"""Pure safety decisions over plain data: is this goal-position write allowed?

This module owns the rules (LeRobot ``max_relative_target`` semantics for the
step from the present position, and the calibrated absolute range of each
motor). It never touches a bus: the caller reads the present positions and
passes them in, so every rule is testable with plain dicts.
"""

from __future__ import annotations

import math
import operator
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


@dataclass(frozen=True, slots=True)
class MotorLimit:
    """One motor's goal rules for one kind of write (normalised or raw), worked out from its facts.

    Why: the facts change only when the customer recalibrates, and the relative limit
    in the write's units takes two unit conversions to find; a control loop writes the
    same motors at 100 Hz. ``compile_limits`` builds these once per shape; the check of
    each goal against them still runs on every write.
    """

    norm_mode: str
    #: The calibration a normalised goal is converted to raw ticks with; None: the goal is raw ticks.
    to_raw_range: MotorRange | None
    #: The cell's calibrated range in raw ticks; None: the absolute rule does not apply.
    cell_bounds: tuple[int, int] | None
    #: The cell's relative limit in the write's units; None: no relative limit.
    relative: float | None
    #: Goals in this closed interval (the write's units) are proven inside ``cell_bounds``
    #: (``proven_inside``): the absolute rule needs no conversion for them. None: always convert.
    inside: tuple[float, float] | None = None


def _linear_to_raw(value: float, norm_mode: str, motor_range: MotorRange) -> float:
    """``to_raw`` without its clamp and its truncation: the straight line the conversion follows."""
    low, high = motor_range.range_min, motor_range.range_max
    if norm_mode == DEGREES:
        return value * _MAX_RES / 360 + (low + high) / 2
    drive = bool(motor_range.drive_mode)
    if norm_mode == RANGE_0_100:
        return ((100 - value if drive else value) / 100) * (high - low) + low
    return (((-value if drive else value) + 100) / 200) * (high - low) + low


def proven_inside(
    norm_mode: str, to_raw_range: MotorRange | None, bounds: tuple[int, int]
) -> tuple[float, float] | None:
    """An interval of goals (the write's units) whose raw ticks are all inside ``bounds``, or None.

    Why: converting each goal to raw ticks is most of the absolute rule's cost at
    100 Hz, and a control loop's goals sit well inside the range. ``to_raw`` is
    monotone in the goal for every mode (a line, a clamp and a truncation, each
    monotone in one direction; IEEE arithmetic rounds monotonically), so an
    interval whose two ends convert inside ``bounds`` holds only goals that
    convert inside too. The ends are found one tick inside each bound through the
    line's inverse, then checked with ``to_raw`` itself: a float error can only
    make the interval smaller (or absent), never admit a goal ``to_raw`` refuses.
    """
    low, high = bounds
    if to_raw_range is None:  # a raw goal is truncated to int: monotone, and the bounds are whole ticks
        return (float(low), float(high))
    if high - low < 2:
        return None
    at_zero = _linear_to_raw(0.0, norm_mode, to_raw_range)
    slope = _linear_to_raw(1.0, norm_mode, to_raw_range) - at_zero
    if not math.isfinite(slope) or slope == 0:
        return None
    ends = sorted(((low + 1 - at_zero) / slope, (high - 1 - at_zero) / slope))
    if not all(math.isfinite(end) for end in ends):
        return None
    for end in ends:
        if not low <= to_raw(end, norm_mode, to_raw_range) <= high:
            return None
    return (ends[0], ends[1])


def compile_limits(
    facts: Mapping[str, MotorFacts], limit: float | Mapping[str, float] | None, *, normalize: bool
) -> dict[str, MotorLimit]:
    """The goal rules of each motor in ``facts`` for writes in ``normalize``'s units."""
    compiled = {}
    for motor, fact in facts.items():
        bounds = to_raw_range = None
        # Normalised without a bus calibration: the real call fails on its own, nothing to check.
        if fact.cell_range is not None and (fact.bus_range is not None or not normalize):
            bounds = (fact.cell_range.range_min, fact.cell_range.range_max)
            to_raw_range = fact.bus_range if normalize else None
        relative = limit_for(limit, motor)
        if relative is not None:
            relative = limit_in_write_units(relative, fact, normalize=normalize)
        inside = None if bounds is None else proven_inside(fact.norm_mode, to_raw_range, bounds)
        compiled[motor] = MotorLimit(fact.norm_mode, to_raw_range, bounds, relative, inside)
    return compiled


def _absolute_violation(motor: str, raw: int, bounds: tuple[int, int]) -> Violation:
    low, high = bounds
    return Violation(motor, "absolute", float(raw), float(high), bounds=(low, high))


@dataclass(frozen=True, slots=True)
class GoalDecision:
    """What becomes of one goal write: the goals to send, which were clamped, and the steps asked."""

    goals: dict[str, float]
    clamped: tuple[str, ...] = ()
    #: Step from the present position per motor, as requested (before any clamp).
    steps: dict[str, float] | None = None
    violation: Violation | None = None


def decide_goals(
    goals: Mapping[str, float],
    present: Mapping[str, float],
    limits: Mapping[str, MotorLimit],
    *,
    normalize: bool,
    clamp: bool,
) -> GoalDecision:
    """The ``clamp``/``trip`` safety policy over one goal write, with each motor's rules compiled.

    A goal outside the calibrated range is always a violation. A step beyond the
    relative limit is a violation under ``trip``; under ``clamp`` the goal is moved
    to present ± limit, as LeRobot's ``ensure_safe_goal_position`` does. Motors
    without rules (not motors of the bus) are left to the real call, which refuses them.
    """
    steps: dict[str, float] = {}
    result: dict[str, float] | None = None  # a copy of the goals, made at the first clamp
    clamped: list[str] = []
    for motor, goal in goals.items():
        here = present.get(motor)
        if here is not None:
            step = steps[motor] = goal - here
        rules = limits.get(motor)
        if rules is None:
            continue
        bounds = rules.cell_bounds
        inside = rules.inside
        if bounds is not None and (inside is None or not inside[0] <= goal <= inside[1]):
            raw = to_raw(goal, rules.norm_mode, rules.to_raw_range) if rules.to_raw_range is not None else int(goal)
            if not bounds[0] <= raw <= bounds[1]:
                return _refused(goals, present, steps, _absolute_violation(motor, raw, bounds))
        relative = rules.relative
        if here is None or relative is None or abs(step) <= relative:
            continue
        if not clamp:
            violation = Violation(motor, "relative", goal, relative, present=here, step=step)
            return _refused(goals, present, steps, violation)
        if result is None:
            result = dict(goals)
        # A raw goal stays whole ticks, inside the limit.
        allowed = relative if normalize else float(math.floor(relative))
        result[motor] = here + math.copysign(allowed, step)
        clamped.append(motor)
    return GoalDecision(dict(goals) if result is None else result, tuple(clamped), steps, None)


@dataclass(frozen=True, slots=True)
class GoalScreen:
    """The goal rules of a fixed list of motors as parallel tuples: a whole write screened in C loops.

    Why: nearly every write of a control loop is one where each goal is inside its
    proven interval (``MotorLimit.inside``) and each step within its relative limit,
    and ``decide_goals`` then clamps nothing and refuses nothing. ``step_sizes`` finds
    exactly those writes with a few ``map`` passes instead of a Python step per
    motor, and returns their step sizes (for the report); for any other write it returns
    None and ``decide_goals`` decides as always. It only ever accepts a write that
    ``decide_goals`` accepts unchanged.
    """

    motors: tuple[str, ...]
    #: Per motor: the proven interval's ends (-inf/inf when the absolute rule does not apply).
    lows: tuple[float, ...]
    highs: tuple[float, ...]
    #: Per motor: the relative limit in the write's units (inf when there is none).
    relative: tuple[float, ...]

    @classmethod
    def build(cls, motors: tuple[str, ...], limits: Mapping[str, MotorLimit]) -> GoalScreen | None:
        """The screen of ``motors`` (in this order), or None when a motor has no rules or no proven interval."""
        lows, highs, relative = [], [], []
        for motor in motors:
            rules = limits.get(motor)
            if rules is None:
                return None  # not a motor of the bus: decide_goals leaves it to the real call
            if rules.cell_bounds is None:
                low, high = -math.inf, math.inf
            elif rules.inside is None:
                return None  # every goal needs the conversion to raw ticks
            else:
                low, high = rules.inside
            lows.append(low)
            highs.append(high)
            relative.append(math.inf if rules.relative is None else rules.relative)
        return cls(motors, tuple(lows), tuple(highs), tuple(relative))

    def step_sizes(self, goals: Mapping[str, float], present: Mapping[str, float]) -> tuple[float, ...] | None:
        """The step sizes (``|goal - present|``, in ``motors`` order) of a write whose every goal passes
        on its own, or None (``decide_goals`` decides then).

        ``goals`` must hold exactly this screen's motors and ``present`` know every one of
        them. A nan goal, position or step fails the comparisons, so it is never accepted here.
        Sizes, not signed steps: the safety report keeps each motor's largest size, and
        nothing else of an accepted write is needed.
        """
        motors = self.motors
        if len(goals) != len(motors):
            return None
        try:
            values = tuple(map(goals.__getitem__, motors))
            sizes = tuple(map(abs, map(operator.sub, values, map(present.__getitem__, motors))))
        except KeyError:
            return None
        if (
            all(map(operator.le, self.lows, values))
            and all(map(operator.le, values, self.highs))
            and all(map(operator.le, sizes, self.relative))
        ):
            return sizes
        return None


def _refused(
    goals: Mapping[str, float], present: Mapping[str, float], steps: dict[str, float], violation: Violation
) -> GoalDecision:
    """The decision on a violation: nothing clamped, and the step of every motor asked (for the report)."""
    for motor, goal in goals.items():
        if motor not in steps and motor in present:
            steps[motor] = goal - present[motor]
    return GoalDecision(dict(goals), (), {m: steps[m] for m in goals if m in steps}, violation)


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
    limits = compile_limits(facts, limit, normalize=normalize)
    return decide_goals(goals, present, limits, normalize=normalize, clamp=False).violation


def decide_goal_write(
    goals: Mapping[str, float],
    present: Mapping[str, float],
    facts: Mapping[str, MotorFacts],
    limit: float | Mapping[str, float] | None,
    *,
    normalize: bool,
    clamp: bool,
) -> GoalDecision:
    """``decide_goals`` with the rules compiled from ``facts`` and ``limit`` for this one write."""
    limits = compile_limits(facts, limit, normalize=normalize)
    return decide_goals(goals, present, limits, normalize=normalize, clamp=clamp)


@dataclass(frozen=True)
class RestWalk:
    """A straight walk of every motor from ``start`` to ``goal`` (raw ticks) at a speed limit.

    It advances by the time that really passed since its previous tick, not by a
    fixed step per tick: on a loaded host ticks run late, and a walk of N fixed
    steps then lasts N late ticks, long enough to outlast a job's grace window
    (the connector was seen killed by its own stop watchdog, torque still on,
    mid-walk). It never makes up lost time: a tick advances at most
    ``max_step_s`` of motion however long the host stalled, so over any stretch
    of ticks the arm moves no faster than the speed limit (a stall costs time,
    never speed). The stop's deadline bounds how long that may take.
    """

    start: Mapping[str, int]
    goal: Mapping[str, int]
    speed_ticks_per_s: float
    max_step_s: float = 0.1

    @property
    def seconds(self) -> float:
        """How long the walk lasts when its ticks are on time."""
        motors = [m for m in self.goal if m in self.start]
        if not motors or self.speed_ticks_per_s <= 0:
            return 0.0
        return max(abs(self.goal[m] - self.start[m]) for m in motors) / self.speed_ticks_per_s

    def advance(self, done: float, since_last_tick_s: float) -> float:
        """The fraction done after a tick ``since_last_tick_s`` after the previous one (``done`` then)."""
        seconds = self.seconds
        if seconds <= 0:
            return 1.0
        step_s = min(max(since_last_tick_s, 0.0), self.max_step_s)
        return min(1.0, done + step_s / seconds)

    def at(self, fraction: float) -> dict[str, int]:
        """Goal per motor (raw ticks) once ``fraction`` of the walk is done."""
        fraction = min(1.0, max(0.0, fraction))
        return {
            m: int(round(self.start[m] + (self.goal[m] - self.start[m]) * fraction))
            for m in self.goal if m in self.start
        }

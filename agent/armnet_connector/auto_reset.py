"""The scripted reset's moves and its report: the connector drives an arm through a cell's reset poses.

This module owns how one reset pose is reached and what a scripted reset
reports. The moves take a job's path exactly, never a shortcut: a bus built as a
job's is (``hardware.create_feetech``: the cell's motors and calibration, the
register policy at the bus's write choke point), and every goal checked by the
motion guard (the interlock, the calibrated range, the step limit and the cell's
``safetyPolicy``) under the arm's device lock. So an interlock that trips (a safety
refusal, the deadline's grace window, the connector's stop) ends the moves at the
next tick. It never decides whether to try again or ask a person
(``CellState.reset`` does) and never judges the scene (the completion monitor does).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from armnet_core.cell_completion import split_pose

from .config import MotorRange
from .errors import RequestError
from .hardware import Handle
from .identity import CellMotor
from .retry import with_read_retry
from .safety import RestWalk, limit_for, ticks_per_unit, to_raw

#: Outcomes of a scripted reset (the metric's ``outcome`` label uses them, and ``try_failed`` for each failed try).
#: It worked: the completion monitor judged the scene back at its start, nobody was involved.
WORKED = "worked"
FELL_BACK = "fell_back"
#: The interlock tripped during it (a safety refusal, the deadline, the connector's stop): no person is asked.
STOPPED = "stopped"

TICK_S = 0.02
#: How far (raw ticks) a servo may end from a pose and the pose still count as reached (as a rest's).
SETTLE_TOLERANCE_TICKS = 25
#: How long an arm that gets no closer to a pose may take before the pose counts as missed.
SETTLE_WAIT_S = 3.0
#: The longest an arm that keeps getting closer may take after its walk.
MAX_SETTLE_S = 30.0
MAX_DETAIL_CHARS = 300


@dataclass(frozen=True)
class AttemptReport:
    """One try of a scripted reset: did the monitor judge the scene back at its start, and why not."""

    number: int
    reset: bool
    detail: str


@dataclass(frozen=True)
class AutoResetReport:
    """One scripted reset: its outcome (``WORKED``, ``FELL_BACK``, ``STOPPED``) and its tries."""

    outcome: str
    attempts: tuple[AttemptReport, ...]
    #: Wall-clock time it ended.
    at: float

    @property
    def message(self) -> str:
        tries = len(self.attempts)
        last = self.attempts[-1].detail if self.attempts else ""
        if self.outcome == WORKED:
            return f"scripted reset worked on try {tries}: {last}"
        if self.outcome == STOPPED:
            return f"scripted reset stopped on try {tries}: {last}"
        return (
            f"scripted reset failed {tries} time(s), the person at the cell is asked to reset it: {last}. "
            "Check the workspace (an object left in the target region, a pose that cannot clear it) "
            "and spec.reset.poses"
        )

    def as_status(self) -> dict[str, Any]:
        return {
            "outcome": self.outcome,
            "at": self.at,
            "message": self.message[:MAX_DETAIL_CHARS * 2],
            "attempts": [{"number": a.number, "reset": a.reset, "detail": a.detail[:MAX_DETAIL_CHARS]}
                         for a in self.attempts],
        }


def pose_targets(
    poses: Sequence[Mapping[str, float]], ranges: Mapping[str, Mapping[str, MotorRange]],
    motors: Mapping[str, Mapping[str, CellMotor]],
) -> list[dict[str, dict[str, int]]]:
    """Each pose as arm -> {motor: raw goal}, converted as the arm's bus converts a job's goal (pure).

    Raises ``ValueError`` naming the pose and joint that is not a motor of the cell, or
    lies outside its calibrated range: the guard would refuse it and trip the interlock.
    """
    targets: list[dict[str, dict[str, int]]] = []
    for number, pose in enumerate(poses):
        split = split_pose(pose, list(ranges))
        raw: dict[str, dict[str, int]] = {}
        for arm, joints in split.items():
            for joint, value in joints.items():
                cell_range = ranges[arm].get(joint)
                motor = motors.get(arm, {}).get(joint)
                if cell_range is None or motor is None:
                    raise ValueError(f"reset.poses[{number}]: arm {arm!r} has no motor {joint!r} in its calibration")
                tick = to_raw(value, motor.norm_mode, cell_range)
                if not cell_range.range_min <= tick <= cell_range.range_max:
                    raise ValueError(
                        f"reset.poses[{number}]: {joint} {value:g} is raw {tick}, outside arm {arm!r}'s calibrated "
                        f"range [{cell_range.range_min}, {cell_range.range_max}]; give a value inside it"
                    )
                raw.setdefault(arm, {})[joint] = tick
        targets.append(raw)
    return targets


#: The mover keeps each step this far inside the cell's relative limit: the guard never has to clamp
#: (or, under ``safetyPolicy: trip``, refuse) the connector's own goals.
STEP_MARGIN = 0.9


def step_limits(safety_limit: float | Mapping[str, float] | None, motors: Mapping[str, CellMotor],
                ranges: Mapping[str, MotorRange]) -> dict[str, int]:
    """Per motor, the largest raw step from the present position the mover sends (pure).

    The cell's ``safetyLimit`` is in each motor's unit (degrees, 0..100); a motor without
    one gets none here, and the walk's speed alone paces it.
    """
    steps: dict[str, int] = {}
    for name, motor in motors.items():
        limit = limit_for(safety_limit, name)
        cell_range = ranges.get(name)
        if limit is not None and cell_range is not None:
            steps[name] = max(1, int(limit * ticks_per_unit(motor.norm_mode, cell_range) * STEP_MARGIN))
    return steps


class PoseMover:
    """Drives one arm's policed bus to raw goals, every write through the motion guard. The caller holds the lock.

    Each goal is the walk's, but never further from the present position than the cell's
    step limit allows (``step_limits``): on a loaded host a late tick, or an arm that
    lags its walk, must not make the connector's own write one the guard clamps (a goal
    clamped short would stay short) or, under ``safetyPolicy: trip``, refuses.
    """

    def __init__(self, handle: Handle, check: Callable[[Handle, str, list[Any], dict[str, Any]], None],
                 refusal: Callable[[], tuple[str, str] | None], speed_ticks_per_s: float,
                 on_lost_reply: Callable[[], None], max_steps: Mapping[str, int] | None = None) -> None:
        self.handle = handle
        self._check = check
        self._refusal = refusal
        self.speed = speed_ticks_per_s
        self._on_lost_reply = on_lost_reply
        self._max_steps = dict(max_steps or {})

    def _call(self, method: str, args: list[Any], kwargs: dict[str, Any]) -> Any:
        """A call as a job's goes: the guard first (it raises, or clamps the goals in place), then the bus."""
        self._check(self.handle, method, args, kwargs)
        return getattr(self.handle.obj, method)(*args, **kwargs)

    def _stop_if_refused(self) -> None:
        refusal = self._refusal()
        if refusal is not None:
            raise RequestError(*refusal)

    def positions(self, motors: list[str]) -> dict[str, int]:
        bus = self.handle.obj
        read = with_read_retry(
            self.handle, "sync_read", lambda: bus.sync_read("Present_Position", motors, normalize=False),
            on_retry=self._on_lost_reply, before_retry=self._stop_if_refused,
        )
        present = {m: int(v) for m, v in read.items()}
        # The guard's step check reuses this read (as a job's own sync_read) instead of reading again.
        self.handle.present[False] = (time.monotonic(), {m: float(v) for m, v in present.items()})
        return present

    def _send(self, goal: Mapping[str, int], present: Mapping[str, int]) -> None:
        """Write ``goal``, each motor at most its step from ``present``."""
        bounded = {}
        for motor, value in goal.items():
            step = self._max_steps.get(motor)
            bounded[motor] = value if step is None else max(present[motor] - step, min(present[motor] + step, value))
        self._call("sync_write", ["Goal_Position", bounded], {"normalize": False})

    def drive(self, goal: Mapping[str, int]) -> str | None:
        """Walk to ``goal`` at the rest speed; None once every motor is within tolerance, else why not.

        Raises ``RequestError`` when the guard refuses a write (the interlock holds, or a goal
        broke a limit under ``safetyPolicy: trip``): no further write is sent.
        """
        motors = list(goal)
        present = self.positions(motors)
        # Hold where it is before torque comes on, so a stale goal cannot make the arm jump.
        self._call("sync_write", ["Goal_Position", dict(present)], {"normalize": False})
        # Acknowledged writes: a lost reply is asked again past its late answer, as every bus call of a job is.
        with_read_retry(self.handle, "enable_torque", lambda: self._call("enable_torque", [motors], {}),
                        on_retry=self._on_lost_reply, before_retry=self._stop_if_refused)
        walk = RestWalk(present, dict(goal), self.speed)
        done, last = 0.0, time.monotonic()
        while done < 1.0:
            time.sleep(TICK_S)
            now = time.monotonic()
            done, last = walk.advance(done, now - last), now
            self._send(walk.at(done), self.positions(motors))
        # Bounded steps may leave the arm short of the pose when the walk ends (a slow host, a small
        # limit): it goes on from where it is, for as long as it gets closer, and then SETTLE_WAIT_S more.
        started = time.monotonic()
        settle_until, closest = started + SETTLE_WAIT_S, None
        while True:
            self._stop_if_refused()
            reached = self.positions(motors)
            errors = {m: goal[m] - reached[m] for m in motors}
            worst = max(motors, key=lambda m: abs(errors[m]))
            now = time.monotonic()
            if abs(errors[worst]) <= SETTLE_TOLERANCE_TICKS:
                return None
            if closest is None or abs(errors[worst]) < closest:
                closest = abs(errors[worst])
                settle_until = min(now + SETTLE_WAIT_S, started + MAX_SETTLE_S)
            if now >= settle_until:
                return (f"{worst} ended {abs(errors[worst])} ticks from the pose (tolerance {SETTLE_TOLERANCE_TICKS}); "
                        "is something in the arm's way?")
            self._send(goal, reached)  # a goal bounded short of the pose on the way is sent again from here
            time.sleep(TICK_S)

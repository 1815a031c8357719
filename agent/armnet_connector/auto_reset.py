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
from .safety import RestWalk, to_raw

#: Outcomes of a scripted reset (the metric's ``outcome`` label uses them, and ``try_failed`` for each failed try).
#: It worked: the completion monitor judged the scene back at its start, nobody was involved.
WORKED = "worked"
FELL_BACK = "fell_back"
#: The interlock tripped during it (a safety refusal, the deadline, the connector's stop): no person is asked.
STOPPED = "stopped"

TICK_S = 0.02
#: How far (raw ticks) a servo may end from a pose and the pose still count as reached (as a rest's).
SETTLE_TOLERANCE_TICKS = 25
SETTLE_WAIT_S = 3.0
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


class PoseMover:
    """Drives one arm's policed bus to raw goals, every write through the motion guard. The caller holds the lock."""

    def __init__(self, handle: Handle, check: Callable[[Handle, str, list[Any], dict[str, Any]], None],
                 refusal: Callable[[], tuple[str, str] | None], speed_ticks_per_s: float,
                 on_lost_reply: Callable[[], None]) -> None:
        self.handle = handle
        self._check = check
        self._refusal = refusal
        self.speed = speed_ticks_per_s
        self._on_lost_reply = on_lost_reply

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
        return {m: int(v) for m, v in read.items()}

    def drive(self, goal: Mapping[str, int]) -> str | None:
        """Walk to ``goal`` at the rest speed; None once every motor is within tolerance, else why not.

        Raises ``RequestError`` when the guard refuses a write (the interlock holds, or a goal
        broke a limit under ``safetyPolicy: trip``): no further write is sent.
        """
        motors = list(goal)
        present = self.positions(motors)
        # Hold where it is before torque comes on, so a stale goal cannot make the arm jump.
        self._call("sync_write", ["Goal_Position", dict(present)], {"normalize": False})
        self._call("enable_torque", [motors], {})
        walk = RestWalk(present, dict(goal), self.speed)
        done, last = 0.0, time.monotonic()
        while done < 1.0:
            time.sleep(TICK_S)
            now = time.monotonic()
            done, last = walk.advance(done, now - last), now
            self._call("sync_write", ["Goal_Position", walk.at(done)], {"normalize": False})
        settle_until = time.monotonic() + SETTLE_WAIT_S
        while True:
            self._stop_if_refused()
            reached = self.positions(motors)
            errors = {m: goal[m] - reached[m] for m in motors}
            worst = max(motors, key=lambda m: abs(errors[m]))
            if abs(errors[worst]) <= SETTLE_TOLERANCE_TICKS:
                return None
            if time.monotonic() >= settle_until:
                return (f"{worst} ended {abs(errors[worst])} ticks from the pose (tolerance {SETTLE_TOLERANCE_TICKS}); "
                        "is something in the arm's way?")
            time.sleep(TICK_S)

"""The job's safety report: what the connector clamped, refused and tripped on, as plain data.

Why: under ``safetyPolicy: clamp`` the connector quietly changes a job's goals;
the job's author and the cell's operator must still see how often, by how much,
and what was refused. The node agent puts ``SafetyReport.as_status()`` into the
job's status at the end (docs/connector.md, "Safety report").

This module owns the report (a frozen dataclass) and the thread-safe recorder
that builds it. It never decides anything: the guard and the register policy
call ``record_*``.
"""

from __future__ import annotations

import operator
import threading
from dataclasses import dataclass, field
from itertools import repeat
from typing import Any

from .restore import RestoreOutcome
from .servo_trace import ServoTrace

#: Refusals kept with their reason; later ones are only counted.
MAX_REFUSALS_KEPT = 50
MAX_REASON_CHARS = 300


@dataclass(frozen=True)
class Refusal:
    kind: str  # "non_finite" | "wrong_type" | "out_of_range" | "relative" | "register" | "calibration"
    motor: str | None
    reason: str


@dataclass(frozen=True)
class SafetyReport:
    """A snapshot of one job's safety record (all plain data)."""

    policy: str
    clamps: dict[str, int] = field(default_factory=dict)
    #: The largest step any goal asked for, per motor, in the units of the write.
    largest_requested_step: dict[str, float] = field(default_factory=dict)
    refusals: tuple[Refusal, ...] = ()
    refusals_total: int = 0
    interlock_trips: int = 0
    #: Per arm: torque read back as off when the connector let go of it (None: never checked).
    torque_off_confirmed: dict[str, bool] = field(default_factory=dict)
    #: Calibration jobs only: what the connector found and restored, per arm.
    calibration: dict[str, tuple[str, ...]] = field(default_factory=dict)
    #: Per arm: the servo registers whose EEPROM differs from the cell's calibration file at
    #: the latest check (when the bus connected, or after a calibration job's restore). Non-empty: the cell's calibration
    #: is not what the file says; the agent sets CalibrationPresent false with these reasons.
    calibration_mismatches: dict[str, tuple[str, ...]] = field(default_factory=dict)
    #: Per arm, per motor: the registers the job changed that the connector wrote back when its
    #: bus let go, as register -> (what the job left, what was written back and read back).
    registers_restored: dict[str, dict[str, dict[str, tuple[int | None, int]]]] = field(default_factory=dict)
    #: Per arm: the registers the latest restore could not put back (empty: the arm is as the job
    #: found it). Non-empty: the next tenant would inherit them; an operator should look at the cell.
    restore_failures: dict[str, tuple[str, ...]] = field(default_factory=dict)
    #: Scripted resets (the cell's ``reset.mode: Scripted``): totals by outcome and the latest one
    #: (``auto_reset.AutoResetReport.as_status``); empty when the job made none.
    auto_resets: dict[str, Any] = field(default_factory=dict)
    #: The job's calls the connector carried to the cell's devices (its buses and cameras, each
    #: past the safety check): 0 says the job never reached the cell, which a pre-flight that
    #: only ran out its seconds must not count as passing.
    device_calls: int = 0

    @property
    def clamps_total(self) -> int:
        return sum(self.clamps.values())

    def as_status(self) -> dict[str, Any]:
        """The camelCase mapping the job's status carries."""
        return {
            "policy": self.policy,
            "clampsPerMotor": dict(self.clamps),
            "largestRequestedStep": dict(self.largest_requested_step),
            "refusals": [{"kind": r.kind, "motor": r.motor, "reason": r.reason} for r in self.refusals],
            "refusalsTotal": self.refusals_total,
            "interlockTrips": self.interlock_trips,
            "torqueOffConfirmed": dict(self.torque_off_confirmed),
            "calibration": {arm: list(notes) for arm, notes in self.calibration.items()},
            "calibrationMismatches": {arm: list(notes) for arm, notes in self.calibration_mismatches.items()},
            "registersRestored": {
                arm: {motor: {register: {"found": found, "restoredTo": value}
                              for register, (found, value) in registers.items()}
                      for motor, registers in motors.items()}
                for arm, motors in self.registers_restored.items()
            },
            "registerRestoreFailures": {arm: list(lines) for arm, lines in self.restore_failures.items()},
            # Only on a job that made scripted resets: the connector's own moves, under the same limits.
            **({"autoResets": dict(self.auto_resets)} if self.auto_resets else {}),
            "deviceCalls": self.device_calls,
        }


class SafetyRecorder:
    """Collects one job's safety events; ``snapshot()`` gives the report."""

    def __init__(self, policy: str) -> None:
        self._policy = policy
        self._lock = threading.Lock()
        self._clamps: dict[str, int] = {}
        self._largest: dict[str, float] = {}
        self._refusals: list[Refusal] = []
        self._refusals_total = 0
        self._trips = 0
        self._torque_off: dict[str, bool] = {}
        self._calibration: dict[str, list[str]] = {}
        self._mismatches: dict[str, list[str]] = {}
        self._restored: dict[str, dict[str, dict[str, tuple[int | None, int]]]] = {}
        self._restore_failures: dict[str, tuple[str, ...]] = {}
        self._auto_resets: dict[str, Any] = {}
        self._device_calls = 0
        #: The cell's servo trace of the job (``servo_trace``): each clamp and refusal, with its time.
        self.trace: ServoTrace | None = None

    def record_steps(self, steps: dict[str, float]) -> None:
        """Keep each motor's largest step (signed steps: ``decide_goals``'s)."""
        self.record_step_sizes(tuple(steps), tuple(map(abs, steps.values())))

    def record_step_sizes(self, motors: tuple[str, ...], sizes: tuple[float, ...]) -> None:
        """Keep each motor's largest step size; a write with no new largest takes no lock.

        Why the look before the lock: at 100 Hz almost every write's steps are below
        the largest seen, and the largest only ever grows, so a step that is not
        larger than a value read without the lock cannot be larger than the value
        under it. Only a write that sets a new largest locks (and looks again).
        """
        largest = self._largest
        # In C loops: is any size above the motor's largest so far (0.0 when none yet)?
        if not any(map(operator.gt, sizes, map(largest.get, motors, repeat(0.0)))):
            return
        with self._lock:
            for motor, size in zip(motors, sizes, strict=True):
                if size > largest.get(motor, 0.0):
                    largest[motor] = size

    def record_device_call(self) -> None:
        """One call of the job's carried to a device (uncontended, the lock costs ~0.1 µs of a ~100 µs bus call)."""
        with self._lock:
            self._device_calls += 1

    def record_clamp(self, motor: str, *, arm: str | None = None, goal: float | None = None,
                     units: str | None = None) -> None:
        """One goal the policy clamped; ``goal``: the goal written instead, in ``units``."""
        with self._lock:
            self._clamps[motor] = self._clamps.get(motor, 0) + 1
        if self.trace is not None:
            self.trace.event("clamp", arm=arm, motor=motor, value=goal, units=units)

    def record_refusal(self, kind: str, motor: str | None, reason: str, *, tripped: bool, arm: str | None = None) -> None:
        if self.trace is not None:
            self.trace.event("refusal", arm=arm, motor=motor, detail=f"{kind}: {reason}")
        with self._lock:
            self._refusals_total += 1
            if len(self._refusals) < MAX_REFUSALS_KEPT:
                self._refusals.append(Refusal(kind, motor, reason[:MAX_REASON_CHARS]))
            if tripped:
                self._trips += 1

    def record_torque_off(self, arm: str, confirmed: bool) -> None:
        with self._lock:
            # Once unconfirmed, stays unconfirmed: the report must not hide a failure.
            self._torque_off[arm] = self._torque_off.get(arm, True) and confirmed

    def record_calibration(self, arm: str, note: str) -> None:
        with self._lock:
            notes = self._calibration.setdefault(arm, [])
            if len(notes) < MAX_REFUSALS_KEPT:
                notes.append(note[:MAX_REASON_CHARS])

    def record_calibration_check(self, arm: str, mismatches: list[str]) -> None:
        """The latest EEPROM check of ``arm``: it replaces the previous one (a restore that worked clears it).

        Each mismatch is also a calibration note, so the report keeps the history.
        """
        for note in mismatches:
            self.record_calibration(arm, note)
        with self._lock:
            if mismatches:
                self._mismatches[arm] = [n[:MAX_REASON_CHARS] for n in mismatches[:MAX_REFUSALS_KEPT]]
            else:
                self._mismatches.pop(arm, None)

    def record_restore(self, arm: str, outcome: RestoreOutcome) -> None:
        """One restore of ``arm``: what it put back (kept for the job) and what it could not (the latest wins)."""
        with self._lock:
            for item in outcome.restored:
                registers = self._restored.setdefault(arm, {}).setdefault(item.motor, {})
                # The first value the job left is the one to report; a later restore of it keeps it.
                found = registers[item.register][0] if item.register in registers else item.found
                registers[item.register] = (found, item.value)
            if outcome.failures:
                self._restore_failures[arm] = tuple(f[:MAX_REASON_CHARS] for f in outcome.failures[:MAX_REFUSALS_KEPT])
            else:
                self._restore_failures.pop(arm, None)

    def record_auto_reset(self, report: dict[str, Any], *, failed_attempts: int) -> None:
        """One scripted reset (``AutoResetReport.as_status``): counted by outcome, its failed tries too
        (``failedAttempts``); the latest is kept whole."""
        with self._lock:
            totals = self._auto_resets
            outcome = str(report.get("outcome"))
            totals[outcome] = int(totals.get(outcome, 0)) + 1
            totals["failedAttempts"] = int(totals.get("failedAttempts", 0)) + failed_attempts
            totals["latest"] = report

    def snapshot(self) -> SafetyReport:
        with self._lock:
            return SafetyReport(
                policy=self._policy,
                clamps=dict(self._clamps),
                largest_requested_step=dict(self._largest),
                refusals=tuple(self._refusals),
                refusals_total=self._refusals_total,
                interlock_trips=self._trips,
                torque_off_confirmed=dict(self._torque_off),
                calibration={arm: tuple(notes) for arm, notes in self._calibration.items()},
                calibration_mismatches={arm: tuple(notes) for arm, notes in self._mismatches.items()},
                registers_restored={arm: {m: dict(r) for m, r in motors.items()} for arm, motors in self._restored.items()},
                restore_failures=dict(self._restore_failures),
                auto_resets=dict(self._auto_resets),
                device_calls=self._device_calls,
            )

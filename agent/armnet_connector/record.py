"""What a host reads from the connector about a job: plain, frozen data.

The node agent turns it into the job's status, the cell's conditions and
metrics; ``armnet run`` prints it. This module owns its shape only; the facts
come from the cell (``CellState``) when the host asks.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass

from .rest import RestReport


@dataclass(frozen=True)
class ConnectorRecord:
    """The connector's account of one job on one cell, at the time it was taken."""

    #: The interlock latched during the job, and why ("safety", "deadline", "reset_timeout", "shutdown").
    interlock_tripped: bool
    trip_reason: str | None
    trip_message: str | None
    #: The job ran past its timeout: its final status is ``timeout``.
    deadline_passed: bool
    safety_violations: int
    #: The latest return to rest of each arm (read back from its servos); ``reached`` False: check the cell.
    rests: tuple[RestReport, ...]
    #: Per arm: the latest torque off, read back from its servos (absent: none yet).
    torque_off_confirmed: Mapping[str, bool]
    #: Every counter of ``cell.Counters``, by name, and the safety report's totals
    #: (``safety_clamps``, ``safety_refusals``, ``safety_trips``) for the agent's metrics.
    counters: Mapping[str, int]
    #: Per arm: how the servos' EEPROM differs from the cell's calibration file at the latest
    #: check (empty: as the file says). Non-empty: CalibrationPresent/HardwareReady false.
    calibration_mismatches: Mapping[str, tuple[str, ...]] = dataclasses.field(default_factory=dict)
    #: Per arm: registers the job changed that the connector could not put back when the job's bus
    #: let go (empty: every arm is as the job found it). Non-empty: the cell needs an operator.
    register_restore_failures: Mapping[str, tuple[str, ...]] = dataclasses.field(default_factory=dict)

    @property
    def calibration_ok(self) -> bool:
        return not any(self.calibration_mismatches.values())

    @property
    def registers_restored(self) -> bool:
        """Every register the job changed is back as it found it (or it changed none)."""
        return not any(self.register_restore_failures.values())

    @property
    def rest_missed(self) -> bool:
        return any(not r.reached for r in self.rests)

    def as_dict(self) -> dict[str, object]:
        """JSON-ready: what the agent puts in a status or a log line."""
        return {
            "interlockTripped": self.interlock_tripped,
            "tripReason": self.trip_reason,
            "tripMessage": self.trip_message,
            "deadlinePassed": self.deadline_passed,
            "safetyViolations": self.safety_violations,
            "rests": [dataclasses.asdict(r) for r in self.rests],
            "torqueOffConfirmed": dict(self.torque_off_confirmed),
            "counters": dict(self.counters),
            "calibrationMismatches": {arm: list(notes) for arm, notes in self.calibration_mismatches.items()},
            "registerRestoreFailures": {arm: list(lines) for arm, lines in self.register_restore_failures.items()},
        }

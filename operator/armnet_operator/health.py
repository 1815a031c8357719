"""Cell health: the derived phase of a Cell from its heartbeat, conditions and spec.

The operator is the one writer of ``Cell.status.phase``; the agent reports only
facts (heartbeat, hardware conditions). Keeping the derivation pure lets the
scheduler and the lifecycle agree on what "available" means.
"""

from __future__ import annotations

from datetime import datetime, timedelta

from .duty_cycle import rest_due
from .model import Cell, CellPhase

UNAVAILABLE = frozenset({CellPhase.OFFLINE, CellPhase.FAULTED, CellPhase.CORDONED, CellPhase.INVALID})


def heartbeat_fresh(cell: Cell, now: datetime, timeout: timedelta) -> bool:
    return cell.last_heartbeat is not None and now - cell.last_heartbeat <= timeout


def heartbeat_lost_for(cell: Cell, now: datetime, timeout: timedelta) -> timedelta:
    """How long past the heartbeat timeout the cell has been silent (zero while fresh)."""
    if cell.last_heartbeat is None:
        return timedelta.max
    return max(timedelta(0), now - cell.last_heartbeat - timeout)


def derive_cell_phase(cell: Cell, occupied: bool, now: datetime, timeout: timedelta) -> CellPhase:
    """Invalid beats Offline beats Faulted beats Cordoned beats Busy beats Resting: the most actionable
    fact wins, and a rest never begins while the cell holds a job (``duty_cycle``)."""
    if cell.invalid:
        return CellPhase.INVALID
    if not heartbeat_fresh(cell, now, timeout):
        return CellPhase.OFFLINE
    if cell.failing_conditions:
        return CellPhase.FAULTED
    if cell.unschedulable:
        return CellPhase.CORDONED
    if occupied:
        return CellPhase.BUSY
    return CellPhase.RESTING if rest_due(cell.duty_cycle, cell.duty, now) else CellPhase.READY


def is_available(phase: CellPhase) -> bool:
    """Available cells can take a job now or once their current job ends."""
    return phase not in UNAVAILABLE

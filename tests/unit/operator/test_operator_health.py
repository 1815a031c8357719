"""Cell health: the most actionable fact decides the phase."""

from __future__ import annotations

import pytest
from armnet_operator.health import derive_cell_phase
from armnet_operator.model import CellPhase
from operator_builders import NOW, TIMING, a_cell

pytestmark = pytest.mark.unit

HB = TIMING.heartbeat_timeout


@pytest.mark.parametrize(("cell", "occupied", "phase"), [
    (a_cell().ready(), False, CellPhase.READY),
    (a_cell().ready(), True, CellPhase.BUSY),
    (a_cell().cordoned().ready(), True, CellPhase.CORDONED),
    (a_cell().failing("HardwareReady").cordoned().ready(), False, CellPhase.FAULTED),
    (a_cell().silent_for(31).failing("HardwareReady").ready(), True, CellPhase.OFFLINE),
    (a_cell().never_heard_from().ready(), False, CellPhase.OFFLINE),
])
def test_offline_beats_faulted_beats_cordoned_beats_busy(cell, occupied, phase) -> None:
    assert derive_cell_phase(cell, occupied, NOW, HB) is phase

"""The simulator's fine thread switch interval stays inside the simulator's own processes.

``interleave_serving_threads`` changes a process-wide setting: a test session, a
connector or a node agent that hosts a simulator in its own process (or starts one
as a child) must keep the interval it had.
"""

from __future__ import annotations

import sys

import pytest
from armnet_sim import SimulatedCellProcess
from armnet_sim.presets import build_cell
from armnet_sim.pty_server import SERVING_SWITCH_INTERVAL_S

pytestmark = pytest.mark.unit


def test_a_simulator_in_this_process_or_in_a_child_leaves_this_processs_switch_interval() -> None:
    before = sys.getswitchinterval()
    assert before != pytest.approx(SERVING_SWITCH_INTERVAL_S)  # else the test proves nothing
    with build_cell("bimanual_so101") as cell:
        assert set(cell.ports()) == {"left", "right"}
    with SimulatedCellProcess("so101") as child:
        assert child.arm.positions()
    assert sys.getswitchinterval() == before

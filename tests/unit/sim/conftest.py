"""Fixtures for the simulator tests: a started SO-101 arm in its own process.

The real-stack tests run the simulator in a child process: the SDK client in
this process busy-polls the port while holding the GIL, and on a loaded
machine an in-process simulator thread can miss LeRobot's ~50 ms timeout.
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from armnet_sim import RemoteArm, SimulatedCellProcess


@pytest.fixture
def so101_arm() -> Iterator[RemoteArm]:
    with SimulatedCellProcess("so101") as cell:
        yield cell.arm

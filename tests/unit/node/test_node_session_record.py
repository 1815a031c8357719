"""The record a job's result carries holds the connector's final release of the arm.

The container launcher's session takes the connector's safety report after the connector has stopped
(torque off through the cell's own bus, read back from the servos), so
``torqueOffConfirmed`` says what the connector did at the job's end, not only
what the job's own closes did; the interlock is read before the stop, which
trips it as teardown.
"""

from __future__ import annotations

import json
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from armnet_launch.cell_spec import resolve_spec
from armnet_launch.sim_cell import LocalCell
from armnet_node.launchers import ContainerSession

pytestmark = pytest.mark.unit


@pytest.fixture
def local_cell() -> Iterator[LocalCell]:
    # Unix socket paths are limited to 108 bytes: pytest's tmp_path is often longer.
    run_dir = Path(tempfile.mkdtemp(prefix="anr-", dir="/tmp"))
    spec = resolve_spec(embodiment=None, preset="so101", task=None, grace_seconds=None)
    try:
        with LocalCell(spec, run_dir) as cell:
            yield cell
    finally:
        shutil.rmtree(run_dir, ignore_errors=True)


def session_on(cell: LocalCell) -> ContainerSession:
    # The record needs neither the engine nor the request: only the cell's connector.
    return ContainerSession(None, None, cell)  # type: ignore[arg-type]


def remote_bus(cell: LocalCell) -> Any:
    from armnet_runtime.lerobot import RemoteFeetechMotorsBus
    from lerobot.motors import Motor, MotorNormMode

    assert cell.connector is not None
    raw = json.loads(cell.layout.arms[0].calibration_file.read_text())
    motors = {
        name: Motor(entry["id"], "sts3215", MotorNormMode.RANGE_0_100 if name == "gripper" else MotorNormMode.DEGREES)
        for name, entry in raw.items()
    }
    return RemoteFeetechMotorsBus(port=cell.connector.robot_endpoint, motors=motors)


def test_the_final_record_confirms_the_connectors_torque_off_of_an_arm_the_job_left_on(
    local_cell: LocalCell,
) -> None:
    bus = remote_bus(local_cell)
    bus.connect()
    bus.enable_torque()  # the job ends holding the arm: only the connector's release lets go
    assert local_cell.connector is not None
    assert local_cell.connector.safety_report().as_status()["torqueOffConfirmed"] == {}

    record = session_on(local_cell).record()

    assert record.safety["torqueOffConfirmed"] == {"arm": True}
    assert local_cell.sim is not None
    assert not any(local_cell.sim.arm.torque_enabled().values())


def test_the_final_record_does_not_count_the_connectors_own_stop_as_an_interlock_trip(
    local_cell: LocalCell,
) -> None:
    record = session_on(local_cell).record()

    assert record.trip_reason is None and record.trip_message is None
    assert record.safety["interlockTrips"] == 0

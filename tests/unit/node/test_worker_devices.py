"""The cell worker and its devices: a failed start leaves nothing behind; only a verdict change wakes the heartbeat."""

from __future__ import annotations

import multiprocessing
from pathlib import Path
from typing import Any

import pytest
from armnet_node.device_health import DEBOUNCE_S, DEVICE_LOST, DeviceState, observe
from armnet_node.deviceplugin.decide import DeviceFact, cell_device_paths
from armnet_node.health import hardware_condition
from armnet_node.metrics import AgentMetrics
from armnet_node.model import parse_cell
from armnet_node.plan import HostPaths
from armnet_node.runner import RunnerDeps
from armnet_node.worker import CellWorker, WorkerSettings

pytestmark = pytest.mark.unit

(ARM,) = cell_device_paths({"arm": "/dev/serial/by-id/usb-arm"})


def worker(state_dir: Path) -> CellWorker:
    cell: dict[str, Any] = {"metadata": {"name": "cell-1", "resourceVersion": "7"},
                            "spec": {"embodiment": "lerobot/so-101", "nodeName": "host-1", "simulated": True,
                                     "task": "pick", "robot": {"robotId": "follower-1", "safetyLimit": 7.5}},
                            "status": {}}
    deps = RunnerDeps(kube=None, launcher=None, paths=HostPaths(state_dir), metrics=AgentMetrics(),
                      link=None, uploads=None)
    return CellWorker(parse_cell(cell), deps, WorkerSettings())


def test_a_worker_whose_start_fails_stops_its_simulator_before_raising(tmp_path: Path) -> None:
    (tmp_path / "cells" / "cell-1").mkdir(parents=True)
    (tmp_path / "cells" / "cell-1" / "dev").write_text("")  # the links' directory cannot be made
    cell = worker(tmp_path)
    with pytest.raises(OSError):
        cell.start()
    assert cell.sim is not None
    assert not [child.name for child in multiprocessing.active_children() if child.name.startswith("armnet-sim-")]


def read(previous: DeviceState, present: bool, t: float) -> DeviceState:
    return observe(previous, [DeviceFact(ARM, "/dev/ttyACM0" if present else None, present)], t)


def test_a_blink_within_the_debounce_does_not_wake_the_heartbeat(tmp_path: Path) -> None:
    cell = worker(tmp_path)
    state = read(DeviceState(), True, 0.0)
    for t, present in ((0.5, False), (1.0, True), (1.5, False), (2.0, True)):
        state = read(state, present, t)
        cell._devices_changed(state)
    assert not cell._wake.is_set()


def test_a_lost_verdict_wakes_the_heartbeat_once(tmp_path: Path) -> None:
    cell = worker(tmp_path)
    state = read(read(DeviceState(), True, 0.0), False, 0.5)
    state = read(state, False, 0.5 + DEBOUNCE_S)
    cell._devices_changed(state)
    assert cell._wake.is_set()
    cell._wake.clear()
    cell._devices_changed(read(state, False, 5.0))  # still lost, the same devices: nothing new to write
    assert not cell._wake.is_set()


def test_hardware_ready_stays_false_while_a_lost_device_is_back_but_not_yet_for_the_debounce(tmp_path: Path) -> None:
    cell = worker(tmp_path)
    lost = read(read(read(DeviceState(), True, 0.0), False, 0.5), False, 0.5 + DEBOUNCE_S)
    cell.devices._state = read(lost, True, 2.5)  # back, the verdict holding: the bus is probed again
    assert cell.devices.state.problems == () and cell.devices.state.lost
    condition = hardware_condition(cell.probe())
    assert (condition.status, condition.reason) == ("False", DEVICE_LOST)

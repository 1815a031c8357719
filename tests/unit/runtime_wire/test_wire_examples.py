"""The LeRobot bus-loop examples, driving the real FeetechMotorsBus against the pty simulator.

Two paths: direct hardware (``ARMNET_LOCAL_CONTAINER``: the example's own
``FeetechMotorsBus`` opens the simulator's pty), and a job (the real
``armnet-runtime`` CLI in a subprocess: import swap, remote proxies and tagged JSON
to a JSON-lines server that, like the connector, builds the real bus on the arm's
device selected by ``?arm=``).
"""

from __future__ import annotations

import importlib.util
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest
from armnet_runtime.context import build_context
from armnet_runtime.decorator import _clear_registration
from armnet_runtime.endpoints import parse_endpoint
from armnet_sim import SimulatedCellProcess
from armnet_sim.calibration import builtin_calibration, write_calibration

from tests.support.jsonl_server_objects import ObjectServer

pytestmark = pytest.mark.unit

EXAMPLES = Path(__file__).resolve().parents[3] / "runtime" / "examples"
MOVED = re.compile(r"(\w+): (\w+) moved ([+-][\d.]+) and back to (-?[\d.]+)")
START = re.compile(r"(\w+): start (\{.*?\})")
JOINTS = {"shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll", "gripper"}


def load_example(name: str, monkeypatch: pytest.MonkeyPatch) -> ModuleType:
    """Import an example the way ``armnet-runtime`` does: its directory on sys.path, one @main."""
    monkeypatch.syspath_prepend(str(EXAMPLES))
    _clear_registration()
    spec = importlib.util.spec_from_file_location(f"armnet_example_{name}", EXAMPLES / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    _clear_registration()
    return module


@pytest.fixture
def work_dir() -> Iterator[Path]:
    path = Path(tempfile.mkdtemp(prefix="armx", dir="/tmp"))  # short: unix socket paths
    yield path
    shutil.rmtree(path, ignore_errors=True)


def start_cell(preset: str, work_dir: Path) -> tuple[SimulatedCellProcess, dict[str, Path]]:
    cell = SimulatedCellProcess(preset, link_dir=work_dir).start()
    files = {
        name: write_calibration(work_dir / f"{name}.json", builtin_calibration(arm_cal))
        for name, arm_cal in {"arm": "so101", "left": "so101_left", "right": "so101_right"}.items()
        if name in cell.arms
    }
    return cell, files


def job_env(monkeypatch: pytest.MonkeyPatch, config: dict[str, Any], args: dict[str, Any]) -> None:
    for key in list(os.environ):
        if key.startswith("ARMNET_"):
            monkeypatch.delenv(key)
    monkeypatch.setenv("ARMNET_JOB_ID", "job-examples")
    monkeypatch.setenv("ARMNET_EMBODIMENT", "lerobot/so-101")
    monkeypatch.setenv("ARMNET_TASK", "bus-loop")
    monkeypatch.setenv("ARMNET_ARGS", json.dumps(args))
    monkeypatch.setenv("ARMNET_CELL_CONFIG", json.dumps(config))
    monkeypatch.setenv("ARMNET_LOCAL_CONTAINER", "1")


def assert_moves(text: str, arms: set[str], degrees: float) -> None:
    """Every joint of every arm moved about ``degrees`` out and came back to where it started."""
    starts = {arm: json.loads(raw) for arm, raw in START.findall(text)}
    assert set(starts) == arms
    moves = MOVED.findall(text)
    assert {(arm, joint) for arm, joint, _, _ in moves} == {(a, j) for a in arms for j in JOINTS}
    for arm, joint, moved, back in moves:
        assert abs(float(moved)) >= degrees - 1.0, (arm, joint, moved)
        assert abs(float(back) - starts[arm][f"{joint}"]) <= 1.0, (arm, joint, back)


def test_bus_loop_on_direct_hardware(
    work_dir: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    example = load_example("bus_loop", monkeypatch)
    cell, files = start_cell("so101", work_dir)
    try:
        job_env(
            monkeypatch,
            {"robot_port": cell.arm.port, "calibration_file_path": str(files["arm"]), "safety_limit": 3.0},
            {"degrees": 4.0},
        )
        result = example.run(build_context())
        assert cell.arm.torque_enabled() == dict.fromkeys(cell.arm.torque_enabled(), True)
    finally:
        cell.stop()
    assert_moves(capsys.readouterr().out, {"arm"}, 4.0)
    assert set(result) == {"final_positions"}
    assert set(result["final_positions"]) == JOINTS


def test_bimanual_on_direct_hardware(
    work_dir: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    example = load_example("bimanual", monkeypatch)
    cell, files = start_cell("bimanual_so101", work_dir)
    try:
        arms = {
            name: {"robot_port": cell.arms[name].port, "calibration_file_path": str(files[name])}
            for name in ("left", "right")
        }
        job_env(monkeypatch, {"arms": arms, "safety_limit": 5.0}, {"degrees": 3.0, "step": 1.5})
        result = example.run(build_context())
    finally:
        cell.stop()
    assert_moves(capsys.readouterr().out, {"left", "right"}, 3.0)
    assert set(result["final_positions"]) == {"left", "right"}


#: What the connector gives a job's reads (agent/armnet_connector/retry.py): a read
#: whose reply a loaded host lost is asked again. This stand-in server has no connector, so
#: its bus asks LeRobot itself; without it one lost reply failed the job (seen with the
#: suite's three sessions on two cores).
READ_RETRIES = 3


class ArmSelectingBus:
    """What the connector does on ``create``: the real bus on the device ``?arm=`` selects,
    whose position reads are asked again after a lost reply, as the connector's are."""

    def __init__(self, ports: dict[str, str]) -> None:
        self.ports = ports
        self.requested: list[str] = []

    def __call__(self, port: str, motors: Any, calibration: Any = None, **kwargs: Any) -> Any:
        from lerobot.motors.feetech import FeetechMotorsBus

        class RetryingReads(FeetechMotorsBus):  # type: ignore[misc]
            def sync_read(self, *args: Any, num_retry: int = READ_RETRIES, **kw: Any) -> Any:
                return super().sync_read(*args, num_retry=num_retry, **kw)

        self.requested.append(port)
        arm = parse_endpoint(port).arm or "arm"
        return RetryingReads(port=self.ports[arm], motors=motors, calibration=calibration, **kwargs)


def test_bimanual_as_a_job_through_the_swap_and_proxies(work_dir: Path) -> None:
    cell, files = start_cell("bimanual_so101", work_dir)
    factory = ArmSelectingBus(cell.ports())
    server = ObjectServer(str(work_dir / "robot.sock"), {"FeetechMotorsBus": factory}).start()
    try:
        config = {
            "arms": {name: {"calibration_file_path": str(files[name])} for name in ("left", "right")},
            "safety_limit": 5.0,
        }
        env = {k: v for k, v in os.environ.items() if not k.startswith("ARMNET_")}
        env.update(
            ARMNET_JOB_ID="job-bimanual", ARMNET_EMBODIMENT="lerobot/bimanual-so-101", ARMNET_TASK="bus-loop",
            ARMNET_ARGS=json.dumps({"degrees": 3.0, "step": 1.5}), ARMNET_CELL_CONFIG=json.dumps(config),
            ARMNET_CELL_SOCKET=server.endpoint,
        )
        cli = Path(sys.executable).parent / "armnet-runtime"
        done = subprocess.run(
            [str(cli), str(EXAMPLES / "bimanual.py")], capture_output=True, text=True, env=env, timeout=240
        )
    finally:
        server.stop()
        cell.stop()
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert factory.requested == [f"{server.endpoint}?arm=left", f"{server.endpoint}?arm=right"]
    assert_moves(done.stdout, {"left", "right"}, 3.0)
    # Per tick the loop costs one sync_read and one sync_write round trip: the
    # method-name cache resolved each method once per bus.
    assert server.count("getattr", "sync_read") == 2
    assert server.count("call", "sync_write") >= 2 * 6 * 2

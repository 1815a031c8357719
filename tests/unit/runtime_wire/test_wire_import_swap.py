"""The LeRobot import swap against the real LeRobot 0.4.4, each case in a fresh interpreter.

A subprocess per case: the swap patches module globals, which must not leak into
other tests, and "already imported" must mean imported in that interpreter.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

import pytest

from tests.support.jsonl_server_objects import ObjectServer

pytestmark = pytest.mark.unit

PRELUDE = """
import json, logging, sys, types
records = []

class Keep(logging.Handler):
    def emit(self, record):
        records.append((record.levelname, record.getMessage()))

logging.getLogger("armnet_runtime").addHandler(Keep())
logging.getLogger("armnet_runtime").setLevel(logging.DEBUG)

def bind_early(name):
    # A robot-like lerobot module that bound the class by name at import time.
    module = types.ModuleType(name)
    exec("from lerobot.motors.feetech import FeetechMotorsBus\\n"
         "from lerobot.cameras.opencv import OpenCVCamera as Camera", module.__dict__)
    sys.modules[name] = module
    return module

def patched_lines():
    return [m for level, m in records if "remote mode" in m and level != "DEBUG"]
"""


def run_case(body: str, *, env: dict[str, str] | None = None) -> dict[str, object]:
    script = PRELUDE + textwrap.dedent(body)
    child_env = {k: v for k, v in os.environ.items() if not k.startswith("ARMNET_")}
    child_env.update(env or {})
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, env=child_env, timeout=240
    )
    assert done.returncode == 0, done.stderr
    result: dict[str, object] = json.loads(done.stdout.strip().splitlines()[-1])
    return result


class EchoBus:
    """Server-side stand-in: records what the customer's constructor call delivered."""

    def __init__(self, port: str, motors: dict[str, object], calibration: object = None) -> None:
        self.port = port
        self.motors = motors

    def describe(self) -> list[str]:
        return [self.port, *(f"{n}:{type(m).__module__}.{type(m).__name__}" for n, m in self.motors.items())]


def test_swap_patches_definitions_reexports_and_early_binders() -> None:
    sock_dir = Path(tempfile.mkdtemp(prefix="armw", dir="/tmp"))
    server = ObjectServer(str(sock_dir / "robot.sock"), {"FeetechMotorsBus": EchoBus}).start()
    try:
        result = run_case(SWAP_CASE, env={"ARMNET_CELL_SOCKET": server.endpoint})
    finally:
        server.stop()
        shutil.rmtree(sock_dir, ignore_errors=True)
    checks = result["checks"]
    assert isinstance(checks, dict) and checks == {name: True for name in checks}
    lines = result["lines"]
    early = result["early"]
    assert isinstance(lines, list) and isinstance(early, list) and len(lines) == 2
    assert lines[0].startswith("armnet LeRobot remote mode installed: patched ")
    patched = set(lines[0].split("patched ", 1)[1].split(", "))
    expected = {
        "lerobot.motors.feetech.FeetechMotorsBus",
        "lerobot.motors.feetech.feetech.FeetechMotorsBus",
        "lerobot.cameras.opencv.OpenCVCamera",
        "lerobot.cameras.opencv.camera_opencv.OpenCVCamera",
        "lerobot.robots.armnet_test_robot.FeetechMotorsBus",
        "lerobot.robots.armnet_test_robot.Camera",
    } | {f"{name}.FeetechMotorsBus" for name in early}
    assert patched == expected
    assert lines[1] == "armnet LeRobot remote mode already installed: nothing new to patch"
    # The customer's constructor call, through the swapped name, reached the connector
    # with the real LeRobot Motor decoded on the far side.
    assert result["described"] == ["/dev/ttyACM0", "gripper:lerobot.motors.motors_bus.Motor"]
    assert server.count("create") == 1


SWAP_CASE = """
import importlib
early = []
try:  # imports torchvision through LeRobot; the case goes on without it where it cannot load
    importlib.import_module("lerobot.teleoperators.so_leader.so_leader")
    early.append("lerobot.teleoperators.so_leader.so_leader")
except Exception:
    pass
robot = bind_early("lerobot.robots.armnet_test_robot")
from armnet_runtime.lerobot import RemoteFeetechMotorsBus, RemoteOpenCVCamera, install_lerobot_remote_mode
install_lerobot_remote_mode()
import lerobot.motors.feetech, lerobot.motors.feetech.feetech
import lerobot.cameras.opencv, lerobot.cameras.opencv.camera_opencv
from lerobot.motors.feetech import FeetechMotorsBus
from lerobot.cameras.opencv import OpenCVCamera, OpenCVCameraConfig
from lerobot.motors import Motor, MotorCalibration, MotorNormMode
checks = {
    "package_bus": lerobot.motors.feetech.FeetechMotorsBus is RemoteFeetechMotorsBus,
    "module_bus": lerobot.motors.feetech.feetech.FeetechMotorsBus is RemoteFeetechMotorsBus,
    "package_cam": lerobot.cameras.opencv.OpenCVCamera is RemoteOpenCVCamera,
    "module_cam": lerobot.cameras.opencv.camera_opencv.OpenCVCamera is RemoteOpenCVCamera,
    "from_import": FeetechMotorsBus is RemoteFeetechMotorsBus and OpenCVCamera is RemoteOpenCVCamera,
    "early_bus": robot.FeetechMotorsBus is RemoteFeetechMotorsBus,
    "early_alias": robot.Camera is RemoteOpenCVCamera,
    "data_types_real": Motor.__module__ == "lerobot.motors.motors_bus"
        and MotorCalibration.__module__ == "lerobot.motors.motors_bus"
        and OpenCVCameraConfig.__module__.startswith("lerobot.cameras.opencv"),
}
for name in early:
    checks[name] = sys.modules[name].FeetechMotorsBus is RemoteFeetechMotorsBus
install_lerobot_remote_mode()
checks["still_proxy"] = lerobot.motors.feetech.FeetechMotorsBus is RemoteFeetechMotorsBus
bus = FeetechMotorsBus(port="/dev/ttyACM0", motors={"gripper": Motor(6, "sts3215", MotorNormMode.RANGE_0_100)})
print(json.dumps({"checks": checks, "lines": patched_lines(), "early": early, "described": bus.describe()}))
"""


def test_swap_imports_nothing_and_swaps_when_the_job_imports_lerobot() -> None:
    """A job pays for LeRobot only when it imports LeRobot: the swap waits for that import."""
    sock_dir = Path(tempfile.mkdtemp(prefix="armw", dir="/tmp"))
    server = ObjectServer(str(sock_dir / "robot.sock"), {"FeetechMotorsBus": EchoBus}).start()
    try:
        result = run_case(LAZY_CASE, env={"ARMNET_CELL_SOCKET": server.endpoint})
    finally:
        server.stop()
        shutil.rmtree(sock_dir, ignore_errors=True)
    assert result["before"] == {"lerobot": [], "torch": False}
    checks = result["checks"]
    assert isinstance(checks, dict) and checks == {name: True for name in checks}
    assert result["lines"] == [
        "armnet LeRobot remote mode: patched lerobot.motors.feetech.feetech.FeetechMotorsBus",
        "armnet LeRobot remote mode: patched lerobot.cameras.opencv.camera_opencv.OpenCVCamera",
        "armnet LeRobot remote mode already installed: nothing new to patch",
    ]
    assert result["described"] == ["/dev/ttyACM0", "gripper:lerobot.motors.motors_bus.Motor"]


LAZY_CASE = """
from armnet_runtime.lerobot import RemoteFeetechMotorsBus, RemoteOpenCVCamera, install_lerobot_remote_mode
from armnet_runtime.lerobot.remote_feetech import RemoteFeetechMotorsBus as Proxy
install_lerobot_remote_mode()
before = {"lerobot": sorted(m for m in sys.modules if m.startswith("lerobot")), "torch": "torch" in sys.modules}
from lerobot.robots.so_follower import so_follower  # binds FeetechMotorsBus at its import
from lerobot.motors.feetech import FeetechMotorsBus
from lerobot.motors.feetech.feetech import FeetechMotorsBus as Defined
from lerobot.motors.motors_bus import SerialMotorsBus
import lerobot.cameras.opencv
from lerobot.cameras import Camera
from lerobot.motors import Motor, MotorNormMode
bus = FeetechMotorsBus(port="/dev/ttyACM0", motors={"gripper": Motor(6, "sts3215", MotorNormMode.RANGE_0_100)})
checks = {
    "package_bus": FeetechMotorsBus is RemoteFeetechMotorsBus,
    "module_bus": Defined is RemoteFeetechMotorsBus,
    "robot_module_bus": so_follower.FeetechMotorsBus is RemoteFeetechMotorsBus,
    "camera": lerobot.cameras.opencv.OpenCVCamera is RemoteOpenCVCamera,
    "virtual_base": isinstance(bus, SerialMotorsBus) and issubclass(RemoteOpenCVCamera, Camera),
}
install_lerobot_remote_mode()
checks["still_proxy"] = lerobot.motors.feetech.FeetechMotorsBus is RemoteFeetechMotorsBus
print(json.dumps({"before": before, "checks": checks, "lines": patched_lines(), "described": bus.describe()}))
"""


def test_camera_configs_become_lerobot_configs_when_the_job_imports_lerobot() -> None:
    """Before the job imports LeRobot's camera they are plain dicts; after, LeRobot's configs."""
    result = run_case(
        """
        from armnet_runtime.cell_config import CameraConfig, build_camera_configs
        configs = build_camera_configs({"front": CameraConfig(index_or_path=0, fps=30, width=64, height=48)})
        before = type(configs["front"]).__name__
        from lerobot.cameras.opencv import OpenCVCameraConfig
        after = configs["front"]
        print(json.dumps({"before": before, "after": type(after).__name__,
                          "fields": [after.width, after.height, after.fps]}))
        """
    )
    assert result == {"before": "dict", "after": "OpenCVCameraConfig", "fields": [64, 48, 30]}


def test_swap_is_skipped_for_local_container() -> None:
    result = run_case(
        """
        from armnet_runtime.lerobot import install_lerobot_remote_mode
        install_lerobot_remote_mode()
        import lerobot.motors.feetech.feetech as feetech
        print(json.dumps({"lines": patched_lines(), "real": feetech.FeetechMotorsBus.__module__,
                          "imported": "lerobot.motors.feetech" in sys.modules}))
        """,
        env={"ARMNET_LOCAL_CONTAINER": "1"},
    )
    assert result["real"] == "lerobot.motors.feetech.feetech"
    assert result["lines"] == [
        "armnet LeRobot remote mode skipped: ARMNET_LOCAL_CONTAINER is set, LeRobot drives the hardware directly"
    ]


def test_swap_is_a_no_op_without_lerobot(tmp_path: Path) -> None:
    import lerobot

    site_packages = Path(lerobot.__file__).parent.parent
    hidden = tmp_path / "site"
    hidden.mkdir()
    for entry in site_packages.iterdir():
        if not entry.name.startswith("lerobot"):
            (hidden / entry.name).symlink_to(entry)
    result = run_case(
        f"""
        sys.path[:] = [p for p in sys.path if p != {str(site_packages)!r}] + [{str(hidden)!r}]
        import importlib.util
        assert importlib.util.find_spec("lerobot") is None
        from armnet_runtime.lerobot import install_lerobot_remote_mode
        install_lerobot_remote_mode()
        print(json.dumps({{"records": [m for _, m in records if "remote mode" in m and not m.startswith("armnet LeRobot remote mode: LeRobot is not")],
                          "lerobot": [m for m in sys.modules if m.startswith("lerobot")]}}))
        """
    )
    assert result == {"records": [], "lerobot": []}

"""A job that uses LeRobot's public API the way code written for a bare arm does.

It reports what it saw (types, ``hasattr`` answers, introspection values, error
types); e2e/test_lerobot_proxy_fidelity.py checks each against what LeRobot's
own classes do on the simulator.
"""

import json
import time
from pathlib import Path

from armnet_runtime import Context, main
from armnet_runtime.errors import RemoteCallError
from lerobot.cameras import Camera
from lerobot.cameras.opencv import OpenCVCamera, OpenCVCameraConfig
from lerobot.motors import Motor, MotorCalibration, MotorNormMode
from lerobot.motors.feetech import FeetechMotorsBus
from lerobot.motors.motors_bus import MotorsBusBase, SerialMotorsBus

JOINTS = ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll")

@main
def run(ctx: Context):
    raw = json.loads(Path(ctx.cell.calibration_file_path).read_text())
    motors = {n: Motor(i, "sts3215", MotorNormMode.DEGREES) for i, n in enumerate(JOINTS, 1)}
    motors["gripper"] = Motor(6, "sts3215", MotorNormMode.RANGE_0_100)
    t0 = time.perf_counter()
    bus = FeetechMotorsBus(port=ctx.cell.robot_port, motors=motors,
                           calibration={n: MotorCalibration(**raw[n]) for n in motors})
    seen = {"build_s": time.perf_counter() - t0}  # reported, not asserted: timing lives in bench/
    bus.connect()
    seen["isinstance_bus"] = [isinstance(bus, SerialMotorsBus), isinstance(bus, MotorsBusBase)]
    seen["hasattr_sync_reader"] = hasattr(bus, "sync_reader")
    seen["getattr_default"] = getattr(bus, "no_such_thing", "default")
    seen["hasattr_setup_motor"] = hasattr(bus, "setup_motor")
    try:
        bus.setup_motor("gripper")
        seen["setup_motor"] = "accepted"
    except RemoteCallError as exc:  # the connector's refusal, naming the method
        seen["setup_motor"] = [type(exc).__name__, str(exc)[:200]]
    seen["ctrl_table_goal"] = list(bus.model_ctrl_table["sts3215"]["Goal_Position"])
    seen["baudrate"] = bus.port_handler.baudrate
    seen["port_name"] = bus.port_handler.port_name
    seen["scan_port"] = {str(k): v for k, v in FeetechMotorsBus.scan_port(ctx.cell.robot_port).items()}
    try:
        FeetechMotorsBus(port="/dev/ttyUSB7", motors=motors)
        seen["foreign_port"] = "accepted"
    except ConnectionError:
        seen["foreign_port"] = "ConnectionError"
    try:
        bus.sync_read("Present_Position", ["not_a_motor"])
        seen["keyerror"] = "accepted"
    except KeyError as exc:
        seen["keyerror"] = str(exc)
    bus.disconnect(disable_torque=False)
    seen["find_cameras"] = [c["id"] for c in OpenCVCamera.find_cameras()]
    config = ctx.camera_configs["front"]
    with OpenCVCamera(config) as cam:
        seen["camera_connected_in_with"] = cam.is_connected
        seen["isinstance_cam"] = isinstance(cam, Camera)
        seen["camera_facts"] = [cam.rotation, cam.capture_width, cam.capture_height, str(cam.backend)]
        seen["read_color_mode"] = list(cam.read(config.color_mode).shape)
    seen["camera_connected_after_with"] = cam.is_connected
    try:
        OpenCVCamera(OpenCVCameraConfig(index_or_path="/dev/video9"))
        seen["foreign_camera"] = "accepted"
    except ConnectionError:
        seen["foreign_camera"] = "ConnectionError"
    return seen

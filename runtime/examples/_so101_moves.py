"""SO-101 helpers shared by the bus-loop examples: motors, calibration, small safe moves.

Only LeRobot's public API is used, so these work the same against the cell's
connector (through the SDK's import swap) and against hardware on this machine.
Every goal is at most ``step`` away from the joint's present position, and
``step`` stays below the cell's safety limit, so the connector never has to refuse a write.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from armnet_runtime import Context

BODY_JOINTS = ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll")
GRIPPER = "gripper"
TOLERANCE = 0.75  # degrees (gripper: percent) counted as "arrived"


def follower_config(ctx: Context) -> Any:
    """LeRobot's ``SO101FollowerConfig`` with the cell's facts in place of the command-line flags.

    The port is the cell's connector endpoint, the calibration the cell's (read-only),
    the cameras the cell's, and LeRobot's ``max_relative_target`` the cell's safety
    limit, so LeRobot clamps each step before the connector ever sees it.
    """
    from lerobot.robots.so_follower import SO101FollowerConfig

    return SO101FollowerConfig(
        port=ctx.cell.robot_port,
        id=ctx.cell.robot_id,
        calibration_dir=ctx.cell.calibration_dir,
        cameras=dict(ctx.camera_configs),
        max_relative_target=ctx.cell.safety_limit,
    )


def so101_motors() -> dict[str, Any]:
    """The six STS3215 servos of an SO-101 arm, as LeRobot's SO follower declares them."""
    from lerobot.motors import Motor, MotorNormMode

    motors = {name: Motor(i, "sts3215", MotorNormMode.DEGREES) for i, name in enumerate(BODY_JOINTS, 1)}
    motors[GRIPPER] = Motor(6, "sts3215", MotorNormMode.RANGE_0_100)
    return motors


def load_calibration(path: Path | str | None) -> dict[str, Any]:
    """Read a LeRobot calibration JSON into ``MotorCalibration`` objects."""
    from lerobot.motors import MotorCalibration

    if path is None:
        raise RuntimeError(
            "this cell has no calibration file (ctx.cell.calibration_file_path is None); "
            "register the arm's calibration on the cell before running a bus loop"
        )
    data = json.loads(Path(path).read_text())
    return {name: MotorCalibration(**fields) for name, fields in data.items()}


def open_bus(port: str, calibration_path: Path | str | None) -> Any:
    """Build and connect the bus exactly as a customer script would."""
    from lerobot.motors.feetech import FeetechMotorsBus

    bus = FeetechMotorsBus(port=port, motors=so101_motors(), calibration=load_calibration(calibration_path))
    bus.connect()
    bus.enable_torque()
    return bus


def move_joint(bus: Any, joint: str, target: float, step: float, settle_s: float) -> float:
    """Walk ``joint`` to ``target`` in moves of at most ``step`` from its present position."""
    present = float(bus.sync_read("Present_Position")[joint])
    for _ in range(int(abs(target - present) / max(step, 1e-6)) * 4 + 8):
        if abs(target - present) <= TOLERANCE:
            break
        delta = max(-step, min(step, target - present))
        bus.sync_write("Goal_Position", {joint: present + delta})
        time.sleep(settle_s)
        present = float(bus.sync_read("Present_Position")[joint])
    return present


def drive_to(bus: Any, goal: dict[str, float], *, step: float = 8.0, within_s: float = 120.0) -> None:
    """Walk several joints at once to ``goal`` in moves of at most ``step`` from where they are."""
    deadline = time.monotonic() + within_s
    while time.monotonic() < deadline:
        present = bus.sync_read("Present_Position")
        if all(abs(present[j] - g) < 0.5 for j, g in goal.items()):
            return
        bus.sync_write("Goal_Position", {j: present[j] + max(-step, min(step, g - present[j])) for j, g in goal.items()})
        time.sleep(0.05)


def exercise_arm(
    bus: Any,
    *,
    degrees: float,
    step: float,
    settle_s: float,
    report: Callable[[str], None],
    label: str = "arm",
) -> dict[str, float]:
    """Move each joint out by ``degrees`` and back, reporting progress; return final positions."""
    start = {name: float(value) for name, value in bus.sync_read("Present_Position").items()}
    report(f"{label}: start {json.dumps({k: round(v, 1) for k, v in start.items()})}")
    for joint in (*BODY_JOINTS, GRIPPER):
        middle = 50.0 if joint == GRIPPER else 0.0  # move towards the middle of the range
        direction = 1.0 if start[joint] <= middle else -1.0
        reached = move_joint(bus, joint, start[joint] + direction * degrees, step, settle_s)
        back = move_joint(bus, joint, start[joint], step, settle_s)
        report(f"{label}: {joint} moved {reached - start[joint]:+.1f} and back to {back:.1f}")
    final = {name: round(float(value), 2) for name, value in bus.sync_read("Present_Position").items()}
    report(f"{label}: done")
    return final


def loop_settings(ctx: Context, safety_limit: float | None) -> dict[str, float]:
    step = float(ctx.args.get("step", 2.0))
    if safety_limit is not None:
        step = min(step, 0.9 * safety_limit)
    return {
        "degrees": float(ctx.args.get("degrees", 5.0)),
        "step": step,
        "settle_s": float(ctx.args.get("settle_s", 0.02)),
    }

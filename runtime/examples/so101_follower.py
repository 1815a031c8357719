"""Drive the cell's SO-101 with LeRobot's own robot class, ``SO101Follower``.

This is the script a LeRobot user runs next to a real arm, with the cell's facts
in place of the command-line flags: the port is the cell's connector endpoint,
the calibration is the cell's (read-only), the cameras are the cell's, and
LeRobot's ``max_relative_target`` is the cell's safety limit, so LeRobot clamps
each step before the connector ever sees it.

    armnet run runtime/examples/so101_follower.py --embodiment lerobot/so-101
"""

from __future__ import annotations

import time
from typing import Any

from _so101_moves import follower_config
from armnet_runtime import Context, main
from lerobot.robots.so_follower import SO101Follower

JOINTS = ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll", "gripper")


@main
def run(ctx: Context) -> dict[str, Any]:
    robot = SO101Follower(follower_config(ctx))
    robot.connect()
    try:
        first = robot.get_observation()
        start = {joint: float(first[f"{joint}.pos"]) for joint in JOINTS}
        ctx.report_progress(f"connected; cameras {sorted(robot.cameras)}")
        offset = float(ctx.args.get("degrees", 3.0))
        target = {f"{joint}.pos": start[joint] + (offset if start[joint] <= 0 else -offset) for joint in JOINTS[:3]}
        for _ in range(int(ctx.args.get("ticks", 30))):  # a 30 Hz loop, as lerobot-record runs it
            robot.send_action(target)
            observation = robot.get_observation()
            time.sleep(1 / 30)
        frames = {name: list(observation[name].shape) for name in robot.cameras}
        reached = {joint: round(float(observation[f"{joint}.pos"]), 2) for joint in JOINTS}
    finally:
        robot.disconnect()
    ctx.report_progress("done")
    return {"start": start, "target": {k.removesuffix(".pos"): v for k, v in target.items()},
            "reached": reached, "frames": frames}

"""Drive both arms of a bimanual SO-101 cell with LeRobot's own ``BiSOFollower``.

LeRobot names each arm's calibration ``<id>_left.json`` / ``<id>_right.json`` in
one directory; ``ctx.cell.prepare_bimanual_calibration_dir()`` lays the cell's
files out that way. Each arm's port is its connector endpoint (``?arm=left``).

    armnet run runtime/examples/bimanual_follower.py --preset bimanual_so101
"""

from __future__ import annotations

import time
from typing import Any

from armnet_runtime import Context, main
from lerobot.robots.bi_so_follower import BiSOFollower, BiSOFollowerConfig
from lerobot.robots.so_follower import SOFollowerConfig

JOINTS = ("shoulder_pan", "shoulder_lift", "elbow_flex")


@main
def run(ctx: Context) -> dict[str, Any]:
    layout = ctx.cell.prepare_bimanual_calibration_dir()
    arms = {
        side: SOFollowerConfig(port=ctx.cell.arms[side].robot_port,
                               max_relative_target=ctx.cell.arms[side].safety_limit)
        for side in ("left", "right")
    }
    robot = BiSOFollower(BiSOFollowerConfig(
        id=layout.robot_id, calibration_dir=layout.calibration_dir,
        left_arm_config=arms["left"], right_arm_config=arms["right"],
    ))
    robot.connect()
    try:
        start = {key: float(value) for key, value in robot.get_observation().items() if key.endswith(".pos")}
        offset = float(ctx.args.get("degrees", 3.0))
        target = {
            f"{side}_{joint}.pos": start[f"{side}_{joint}.pos"] + (offset if start[f"{side}_{joint}.pos"] <= 0 else -offset)
            for side in ("left", "right") for joint in JOINTS
        }
        for _ in range(int(ctx.args.get("ticks", 30))):
            robot.send_action(target)
            observation = robot.get_observation()
            time.sleep(1 / 30)
        reached = {key: round(float(value), 2) for key, value in observation.items() if key.endswith(".pos")}
    finally:
        robot.disconnect()
    ctx.report_progress("done")
    return {"target": target, "reached": reached}

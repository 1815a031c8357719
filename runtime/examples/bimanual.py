"""Drive both arms of a bimanual SO-101 cell with LeRobot's ``FeetechMotorsBus``.

Each arm of ``ctx.cell.arms`` has its own port (in a job: the connector endpoint
with ``?arm=left`` / ``?arm=right``), calibration file and safety limit. The arms
move one after the other, each joint a few degrees out and back in small steps.
"""

from __future__ import annotations

from typing import Any

from _so101_moves import exercise_arm, loop_settings, open_bus
from armnet_runtime import Context, main

ARMS = ("left", "right")


@main
def run(ctx: Context) -> dict[str, Any]:
    missing = [name for name in ARMS if name not in ctx.cell.arms]
    if missing:
        raise RuntimeError(f"this cell has no arm(s) {missing}; a bimanual job needs a cell with arms {list(ARMS)}")
    buses = {}
    try:
        for name in ARMS:
            arm = ctx.cell.arms[name]
            buses[name] = open_bus(arm.robot_port, arm.calibration_file_path)
        final = {
            name: exercise_arm(bus, report=ctx.report_progress, label=name,
                               **loop_settings(ctx, ctx.cell.arms[name].safety_limit))
            for name, bus in buses.items()
        }
    finally:
        for bus in buses.values():
            bus.disconnect(disable_torque=False)
    return {"final_positions": final}

"""Drive an SO-101 arm with LeRobot's own ``FeetechMotorsBus``: connect, read, move, read back.

In an armnet job ``ctx.cell.robot_port`` is the cell's connector endpoint and the
SDK's import swap hands out the remote bus, so this file runs unchanged against a
simulated cell, a real cell, or (``ARMNET_LOCAL_CONTAINER=1`` and a device path)
an arm plugged into this machine. The moves live in ``_so101_moves.py`` next to it
(``armnet-runtime`` puts the script's directory on ``sys.path``).

Arguments (``ARMNET_ARGS``): ``degrees`` (how far to move each joint, default 5),
``step`` (largest move per write, default 2, capped below the safety limit),
``settle_s`` (wait after each write, default 0.02).
"""

from __future__ import annotations

from typing import Any

from _so101_moves import exercise_arm, loop_settings, open_bus
from armnet_runtime import Context, main


@main
def run(ctx: Context) -> dict[str, Any]:
    if not ctx.cell.robot_port:
        raise RuntimeError("this job has no robot: ctx.cell.robot_port is not set (run it on an SO-101 cell)")
    bus = open_bus(ctx.cell.robot_port, ctx.cell.calibration_file_path)
    try:
        final = exercise_arm(bus, report=ctx.report_progress, **loop_settings(ctx, ctx.cell.safety_limit))
    finally:
        bus.disconnect(disable_torque=False)
    return {"final_positions": final}

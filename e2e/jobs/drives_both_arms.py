"""Drives each arm of a bimanual cell a few degrees out and back (needs ``_so101_moves.py``).

Each arm through its own port (``ctx.cell.arms[name].robot_port``), calibration
and safety limit, as ``runtime/examples/bimanual.py`` does, in fewer moves and
with its reads and its connect retried: on a loaded test host (three suites on
two cores) a starved connector sidecar drops a servo reply now and then, and what
this job checks is that both arms reach their connector, not read latency.
LeRobot's connect pings each servo once, so one lost reply fails its motor check.
"""

import time

from _so101_moves import TOLERANCE, load_calibration, so101_motors
from armnet_runtime import Context, main
from lerobot.motors.feetech import FeetechMotorsBus

ARMS = ("left", "right")
JOINT = "wrist_roll"


def open_bus(port, calibration_path, tries=3):
    """Connect, asked again when the motor check missed a reply; a servo really missing fails every try."""
    bus = FeetechMotorsBus(port=port, motors=so101_motors(), calibration=load_calibration(calibration_path))
    for attempt in range(tries):
        try:
            bus.connect()
            break
        except RuntimeError as error:
            if "motor check failed" not in str(error) or attempt == tries - 1:
                raise
            if bus.is_connected:  # the port opened before the check failed
                bus.disconnect(disable_torque=False)
            time.sleep(0.2)
    bus.enable_torque()
    return bus


def position(bus, joint):
    return float(bus.sync_read("Present_Position", num_retry=5)[joint])


def go(bus, joint, target, within_s=5.0):
    """Write the goal, then read until the joint is there (or ``within_s`` passed): where it got."""
    bus.sync_write("Goal_Position", {joint: target})
    end = time.monotonic() + within_s
    present = position(bus, joint)
    while abs(present - target) > TOLERANCE and time.monotonic() < end:
        time.sleep(0.05)
        present = position(bus, joint)
    return present


@main
def run(ctx: Context):
    missing = [name for name in ARMS if name not in ctx.cell.arms]
    if missing:
        raise RuntimeError(f"this cell has no arm(s) {missing}; a bimanual job needs arms {list(ARMS)}")
    moved = {}
    for name in ARMS:
        arm = ctx.cell.arms[name]
        bus = open_bus(arm.robot_port, arm.calibration_file_path)
        try:
            start = position(bus, JOINT)
            step = min(2.0, 0.9 * arm.safety_limit) if arm.safety_limit else 2.0
            target = start + (step if start <= 0 else -step)
            reached = go(bus, JOINT, target)
            back = go(bus, JOINT, start)
            moved[name] = {"start": round(start, 2), "reached": round(reached, 2), "back": round(back, 2)}
        finally:
            bus.disconnect(disable_torque=False)
        ctx.report_progress(f"{name}: {moved[name]}")
    return {"moved": moved}

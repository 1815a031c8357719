"""A job that asks the arm for a position far outside its calibrated range (needs ``_so101_moves.py``).

Refused under either safety policy (a step only beyond the relative limit would
be clamped, as LeRobot does, under the default): the connector trips the
interlock and the job's write raises ``SafetyViolation``.
"""

from _so101_moves import open_bus
from armnet_runtime import Context, main


@main
def run(ctx: Context):
    bus = open_bus(ctx.cell.robot_port, ctx.cell.calibration_file_path)
    present = float(bus.sync_read("Present_Position")["shoulder_pan"])
    bus.sync_write("Goal_Position", {"shoulder_pan": present + 1000.0})
    return "unreachable"

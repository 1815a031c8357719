"""An evaluation nobody attends (needs ``_so101_moves.py``): reset, drive, score, ``rollouts`` times.

The cell has a scripted reset (``spec.reset.mode: Scripted``) and a completion monitor
watching the simulator's target pad. Each rollout begins with ``ctx.cell.reset()``,
which returns only once the connector drove the arm through the cell's reset pose and
the monitor judged the scene back at its start; nobody confirms anything. Odd rollouts
then drive the arm onto the target, even ones stop short of it. The job returns what
the monitor answered and where the arm really was, after each reset and at each end.
"""


from _so101_moves import drive_to, open_bus
from armnet_runtime import Context, main

TARGET = {"shoulder_lift": 20.0, "elbow_flex": 40.0, "wrist_flex": 0.0}  # armnet_sim.render.TARGET_POSE
SHORT = {**TARGET, "elbow_flex": 25.0}
CHECKS = 10  # is_complete(block=True) waits for a frame captured after each check


def where(bus, joints):
    present = bus.sync_read("Present_Position")
    return {j: round(float(present[j]), 1) for j in joints}


@main
def run(ctx: Context):
    rollouts = int(ctx.args.get("rollouts", 10))
    bus = open_bus(ctx.cell.robot_port, ctx.cell.calibration_file_path)
    seen = []
    for index in range(1, rollouts + 1):
        ctx.cell.reset()
        after_reset = where(bus, TARGET)
        ctx.cell.rollout_begin(index=index, total=rollouts, outcome_controls=False)
        drive_to(bus, TARGET if index % 2 else SHORT, within_s=60)
        complete = False
        for _ in range(CHECKS):
            if ctx.cell.is_complete(block=True).complete:
                complete = True
                break
        seen.append({"complete": complete, "afterReset": after_reset, "ended": where(bus, TARGET)})
        ctx.cell.rollout_end()
    bus.disconnect(disable_torque=False)
    return seen

"""An evaluation of two rollouts on a cell whose completion monitor watches the target pad (needs ``_so101_moves.py``).

Rollout 1 drives the arm onto the simulator's target and asks until the monitor says
complete; rollout 2 stops short of it. Nobody at the cell marks anything: the monitor's
verdicts are what ``status.rollouts`` must show.
"""


from _so101_moves import drive_to, open_bus
from armnet_runtime import Context, main

TARGET = {"shoulder_lift": 20.0, "elbow_flex": 40.0, "wrist_flex": 0.0}  # armnet_sim.render.TARGET_POSE
SHORT = {**TARGET, "elbow_flex": 25.0}


@main
def run(ctx: Context):
    bus = open_bus(ctx.cell.robot_port, ctx.cell.calibration_file_path)
    seen = []
    for index, goal in ((1, TARGET), (2, SHORT)):
        ctx.cell.rollout_begin(index=index, total=2, outcome_controls=False)
        drive_to(bus, goal)
        for _ in range(10):  # each check waits for a frame captured after it to be scored
            status = ctx.cell.is_complete(block=True)
            if status.complete:
                break
        seen.append(bool(status.complete))
        ctx.cell.rollout_end()
    bus.disconnect(disable_torque=False)
    return {"complete": seen}

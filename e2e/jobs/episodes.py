"""``args.episodes`` rollouts on the arm, each a move out and back; it stops early once told to shut down.

Between rollouts it asks ``ctx.is_shutting_down()``: a job preempted for another
tenant (or cancelled) ends after the rollout it is in, with how far it got as its
return value. Every write inside a rollout is counted and each refusal recorded:
a job stopped only at an episode boundary never has a move refused mid-rollout.
"""

import time

from _so101_moves import move_joint, open_bus
from armnet_runtime import Context, main


@main
def run(ctx: Context):
    bus = open_bus(ctx.cell.robot_port, ctx.cell.calibration_file_path)
    total = int(ctx.args.get("episodes", 5))
    hold = float(ctx.args.get("hold", 0.5))
    done, refused = 0, []
    start = float(bus.sync_read("Present_Position")["elbow_flex"])
    for index in range(1, total + 1):
        if ctx.is_shutting_down():
            break
        ctx.cell.rollout_begin(index=index, total=total, outcome_controls=False)
        try:
            move_joint(bus, "elbow_flex", start + 6.0, 3.0, 0.05)
            time.sleep(hold)
            move_joint(bus, "elbow_flex", start, 3.0, 0.05)
        except Exception as exc:  # noqa: BLE001 - the test reads what was refused, and where
            refused.append(f"rollout {index}: {type(exc).__name__}: {exc}")
        ctx.cell.rollout_end()
        done = index
        print(f"rollout {index} done", flush=True)
    bus.disconnect(disable_torque=False)
    return {"episodes_done": done, "of": total, "refused_mid_rollout": refused}

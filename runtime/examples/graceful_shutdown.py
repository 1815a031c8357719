"""A long-running loop that stops cleanly when the cell's deadline passes.

At the job's timeout the cell trips its interlock and opens a grace window
(``ctx.cell.is_shutting_down()`` turns true). A job that notices it can stop
and return what it has: its return value is kept and the job ends ``timeout``.
A job that ignores it is killed when the grace window closes.

    armnet run runtime/examples/graceful_shutdown.py --timeout 3 --grace 5
"""

import time

from armnet_runtime import Context, main


@main
def run(ctx: Context):
    period_s = float(ctx.args.get("period_s", 0.05))
    max_seconds = float(ctx.args.get("max_seconds", 3600))
    started = time.monotonic()
    steps = 0
    while not ctx.cell.is_shutting_down():
        if time.monotonic() - started > max_seconds:
            break
        steps += 1  # one unit of work (an episode step, a rollout, ...)
        if steps % 20 == 0:
            ctx.report_progress(f"{steps} steps done")
        time.sleep(period_s)
    return {
        "steps": steps,
        "stopped_for_shutdown": ctx.cell.is_shutting_down(),
        "elapsed_s": round(time.monotonic() - started, 3),
    }

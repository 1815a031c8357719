"""Ask the cell for a workspace reset between episodes.

``ctx.cell.reset()`` moves the arm slowly to its rest pose, then waits for
the cell operator to confirm the workspace is reset. In ``armnet run`` the
operator is you, at the terminal (or ``--auto-confirm-reset`` for scripted
runs). With no confirmation within the cell's reset timeout the call raises
``ResetTimeoutException`` and the cell's interlock trips.

    armnet run runtime/examples/reset.py --auto-confirm-reset
"""

import time

from armnet_runtime import Context, main


@main
def run(ctx: Context):
    episodes = int(ctx.args.get("episodes", 1))
    waited = []
    for episode in range(episodes):
        ctx.report_progress(f"episode {episode + 1}/{episodes}: asking for a reset")
        started = time.monotonic()
        ctx.cell.reset()
        waited.append(round(time.monotonic() - started, 3))
    return {"resets": episodes, "waited_s": waited}

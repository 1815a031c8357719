"""Prints ``line NNN`` and reports it as progress, ``args.lines`` times, ``args.pause`` seconds apart.

How far it got is in the job's progress, which lets a test act mid-job (kill
the agent, cancel, kill the sidecar) and then check that every line arrived once.
"""

import time

from armnet_runtime import Context, main


@main
def run(ctx: Context):
    for i in range(ctx.args.get("lines", 30)):
        print(f"line {i:03d}", flush=True)
        ctx.report_progress(f"line {i}")
        time.sleep(ctx.args.get("pause", 0.25))
    return {"lines": ctx.args.get("lines", 30)}

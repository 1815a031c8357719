"""Prints ``line NNN`` and reports it as progress, ``args.lines`` times, ``args.pause`` seconds apart.

How far it got is in the job's progress, which lets a test act mid-job (kill
the agent, cancel, kill the sidecar) and then check that every line arrived once.
With ``args.hold_at`` it stops after that line until a file ``go`` appears in its
output directory (the test writes it on the host, ``release`` in the tests): a test
that must act mid-job then does, however slowly the host runs its own steps.
"""

import os
import time
from pathlib import Path

from armnet_runtime import Context, main

HOLD_LIMIT_S = 600


@main
def run(ctx: Context):
    hold_at = ctx.args.get("hold_at")
    for i in range(ctx.args.get("lines", 30)):
        print(f"line {i:03d}", flush=True)
        ctx.report_progress(f"line {i}")
        if i == hold_at:
            go = Path(os.environ["ARMNET_OUTPUT_DIR"]) / "go"
            deadline = time.monotonic() + HOLD_LIMIT_S
            while not go.exists() and time.monotonic() < deadline:
                time.sleep(0.1)
        time.sleep(ctx.args.get("pause", 0.25))
    return {"lines": ctx.args.get("lines", 30)}

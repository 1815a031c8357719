"""A job that never looks at ``ctx.cell.is_shutting_down()``: only a kill at the end of grace ends it."""

import time

from armnet_runtime import Context, main


@main
def run(ctx: Context):
    while True:
        time.sleep(0.1)

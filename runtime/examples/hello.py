"""The smallest armnet job: report progress, read an argument, return a result.

Run it locally with the SDK alone::

    ARMNET_JOB_ID=local ARMNET_EMBODIMENT=lerobot/so-101 ARMNET_TASK=demo \
    ARMNET_ARGS='{"name": "robot"}' armnet-runtime runtime/examples/hello.py
"""

from armnet_runtime import Context, main


@main
def run(ctx: Context) -> dict[str, object]:
    name = ctx.args.get("name", "world")
    ctx.report_progress(f"hello, {name}")
    steps = int(ctx.args.get("steps", 3))
    for step in range(1, steps + 1):
        ctx.report_progress(f"step {step}/{steps}")
    return {"greeting": f"hello, {name}", "steps": steps, "job_id": ctx.job_id}

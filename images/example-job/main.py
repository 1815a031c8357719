"""An example customer job: greets, reports progress, returns a result.

``images/example-job/Containerfile`` puts it at /app/main.py on the runtime base image.
``args.seconds`` (default 0) keeps it running that long, reporting progress each
second: the chart's install test upgrades the release while such a job runs.
"""

import time

from armnet_runtime import Context, main


@main
def run(ctx: Context) -> dict[str, object]:
    name = ctx.args.get("name", "world")
    ctx.report_progress(f"hello, {name}")
    for second in range(int(ctx.args.get("seconds", 0))):
        time.sleep(1)
        ctx.report_progress(f"hello, {name} ({second + 1} s)")
    return {"greeting": f"hello, {name}", "job_id": ctx.job_id}

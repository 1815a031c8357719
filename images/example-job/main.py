"""An example customer job: greets, reports progress, returns a result.

``images/example-job/Containerfile`` puts it at /app/main.py on the runtime base image.
"""

from armnet_runtime import Context, main


@main
def run(ctx: Context) -> dict[str, object]:
    name = ctx.args.get("name", "world")
    ctx.report_progress(f"hello, {name}")
    return {"greeting": f"hello, {name}", "job_id": ctx.job_id}

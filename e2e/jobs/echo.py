"""Returns its args, the length of its ``API_TOKEN`` secret (never the value) and its job id."""

import os

from armnet_runtime import Context, main


@main
def run(ctx: Context):
    ctx.report_progress("echoing")
    return {"args": ctx.args, "secret_length": len(ctx.secrets.get("API_TOKEN", "")),
            "job_id": os.environ["ARMNET_JOB_ID"]}

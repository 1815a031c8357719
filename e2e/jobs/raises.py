"""A job that prints a line and raises: it must end ``failed`` with its traceback and output."""

from armnet_runtime import Context, main


@main
def run(ctx: Context):
    print("about to fail", flush=True)
    raise ValueError("the gripper saw no cube")

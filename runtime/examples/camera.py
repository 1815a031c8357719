"""Read one frame from the cell's ``front`` camera with LeRobot's own OpenCVCamera.

The code is what you would write next to a real robot: ``ctx.camera_configs``
holds the cell's ``OpenCVCameraConfig`` objects, and on an armnet cell the
camera is served by the connector (a simulated camera on a simulated cell).

    armnet run runtime/examples/camera.py --embodiment lerobot/so-101
"""

from armnet_runtime import Context, main
from lerobot.cameras.opencv import OpenCVCamera


@main
def run(ctx: Context):
    name = ctx.args.get("camera", "front")
    if name not in ctx.camera_configs:
        raise KeyError(f"this cell has no camera {name!r}; it has {sorted(ctx.camera_configs)}")
    camera = OpenCVCamera(ctx.camera_configs[name])
    camera.connect()
    try:
        frame = camera.read()
        ctx.report_progress(f"read a {frame.shape[1]}x{frame.shape[0]} frame from {name!r}")
        later = camera.async_read(timeout_ms=1000)
    finally:
        camera.disconnect()
    return {
        "camera": name,
        "shape": list(frame.shape),
        "dtype": str(frame.dtype),
        "async_shape": list(later.shape),
        "mean": float(frame.mean()),
    }

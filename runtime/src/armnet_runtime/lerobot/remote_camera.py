"""``RemoteOpenCVCamera``: LeRobot's ``OpenCVCamera`` served by the cell connector.

The camera config's ``index_or_path`` names a camera of the cell; the connector
opens the real device (or the simulated one) and frames come back as arrays,
through the connector's shared-memory frame area (``frame_reads``).
"""

from __future__ import annotations

import os
from typing import Any

from armnet_runtime import env
from armnet_runtime.cell_config import CellConfigError, parse_cell_config
from armnet_runtime.lerobot.frame_reads import FrameReads
from armnet_runtime.lerobot.remote_feetech import cell_socket_endpoint
from armnet_runtime.lerobot.remote_object import RemoteObjectProxy


def cell_cameras() -> list[dict[str, Any]]:
    """The cell's cameras in ``OpenCVCamera.find_cameras()``'s shape, from ``ARMNET_CELL_CONFIG``.

    ``id`` is what ``OpenCVCameraConfig(index_or_path=...)`` accepts on this cell;
    the profile is the one the cell serves. Scanning ``/dev/video*`` from a job
    would find nothing (the devices belong to the connector), so the cell's own
    list is the honest answer.
    """
    raw = os.environ.get(env.CELL_CONFIG, "").strip()
    if not raw:
        return []
    try:
        config = parse_cell_config(raw)
    except CellConfigError as exc:
        raise RuntimeError(f"OpenCVCamera.find_cameras(): {exc}") from None
    return [
        {
            "name": f"armnet cell camera {name!r}",
            "type": "OpenCV",
            "id": camera.index_or_path,
            "backend_api": "armnet-connector",
            "default_stream_profile": {
                "format": None, "fourcc": camera.fourcc,
                "width": camera.width, "height": camera.height, "fps": camera.fps,
            },
        }
        for name, camera in config.camera_configs.items()
    ]


class RemoteOpenCVCamera(FrameReads, RemoteObjectProxy):
    """Drop-in proxy for LeRobot's ``OpenCVCamera(config)``, reached through ``ARMNET_CELL_SOCKET``."""

    _remote_class = "OpenCVCamera"

    @classmethod
    def _resolve_endpoint(
        cls, args: tuple[Any, ...], kwargs: dict[str, Any]
    ) -> tuple[str, tuple[Any, ...], dict[str, Any]]:
        return cell_socket_endpoint(cls.__name__), args, kwargs

    @staticmethod
    def find_cameras() -> list[dict[str, Any]]:
        """The cell's cameras (``OpenCVCamera.find_cameras``): ``id`` goes into ``index_or_path``."""
        return cell_cameras()

    def __enter__(self) -> RemoteOpenCVCamera:
        """``with OpenCVCamera(config) as cam:`` connects, as LeRobot's ``Camera`` does."""
        self.connect()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: object) -> None:
        """Disconnects even when the block raised; the block's exception propagates."""
        self.disconnect()

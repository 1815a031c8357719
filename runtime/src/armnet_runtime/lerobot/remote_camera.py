"""``RemoteOpenCVCamera``: LeRobot's ``OpenCVCamera`` served by the cell connector.

The camera config's ``index_or_path`` names a camera of the cell; the connector
opens the real device (or the simulated one) and frames come back as arrays,
through the connector's shared-memory frame area (``frame_reads``).
"""

from __future__ import annotations

from typing import Any

from armnet_runtime.lerobot.frame_reads import FrameReads
from armnet_runtime.lerobot.remote_feetech import cell_socket_endpoint
from armnet_runtime.lerobot.remote_object import RemoteObjectProxy


class RemoteOpenCVCamera(FrameReads, RemoteObjectProxy):
    """Drop-in proxy for LeRobot's ``OpenCVCamera(config)``, reached through ``ARMNET_CELL_SOCKET``."""

    _remote_class = "OpenCVCamera"

    @classmethod
    def _resolve_endpoint(
        cls, args: tuple[Any, ...], kwargs: dict[str, Any]
    ) -> tuple[str, tuple[Any, ...], dict[str, Any]]:
        return cell_socket_endpoint(cls.__name__), args, kwargs

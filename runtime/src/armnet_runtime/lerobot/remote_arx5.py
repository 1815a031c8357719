"""``RemoteARX5Arm``: an ARX5 arm served by the cell connector (cells with the ARX5 SDK)."""

from __future__ import annotations

from typing import Any

from armnet_runtime.lerobot.remote_feetech import cell_socket_endpoint
from armnet_runtime.lerobot.remote_object import RemoteObjectProxy


class RemoteARX5Arm(RemoteObjectProxy):
    """Proxy for ``arx5_common.ARX5Arm``, reached through ``ARMNET_CELL_SOCKET``."""

    _remote_class = "ARX5Arm"

    @classmethod
    def _resolve_endpoint(
        cls, args: tuple[Any, ...], kwargs: dict[str, Any]
    ) -> tuple[str, tuple[Any, ...], dict[str, Any]]:
        return cell_socket_endpoint(cls.__name__), args, kwargs

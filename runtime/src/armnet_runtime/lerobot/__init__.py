"""LeRobot integration: remote proxies for the cell's hardware and the import swap.

In a job, the connector sidecar owns the serial bus and cameras. The proxies here
stand in for LeRobot's classes in the customer's container and forward every call
over the connector protocol (runtime/PROTOCOL.md); ``install_lerobot_remote_mode``
makes ``from lerobot... import FeetechMotorsBus`` hand out the proxy.
"""

from __future__ import annotations

from armnet_runtime.errors import RemoteAttributeError
from armnet_runtime.lerobot.import_swap import install_lerobot_remote_mode
from armnet_runtime.lerobot.remote_arx5 import RemoteARX5Arm
from armnet_runtime.lerobot.remote_camera import RemoteOpenCVCamera
from armnet_runtime.lerobot.remote_feetech import RemoteFeetechMotorsBus
from armnet_runtime.lerobot.remote_object import (
    IS_CONNECTED_TTL_S,
    DeviceRefused,
    ReadOnlyView,
    RemoteContextManager,
    RemoteObjectProxy,
)

__all__ = [
    "IS_CONNECTED_TTL_S",
    "DeviceRefused",
    "RemoteARX5Arm",
    "RemoteAttributeError",
    "RemoteContextManager",
    "RemoteFeetechMotorsBus",
    "RemoteObjectProxy",
    "RemoteOpenCVCamera",
    "ReadOnlyView",
    "install_lerobot_remote_mode",
]

"""``RemoteFeetechMotorsBus``: LeRobot's ``FeetechMotorsBus`` served by the cell connector.

The customer passes ``port=ctx.cell.robot_port``, which in a job is a connector
endpoint (``unix:///run/armnet/robot.sock``, maybe with ``?arm=left``). The proxy
connects to that endpoint and sends the ``port`` unchanged, so the connector can
map the arm selector to the arm's real serial device.
"""

from __future__ import annotations

import os
from typing import Any

from armnet_runtime import env
from armnet_runtime.endpoints import looks_like_connector_endpoint
from armnet_runtime.errors import ConnectorUnavailable
from armnet_runtime.lerobot.remote_object import RemoteObjectProxy


def _port_argument(args: tuple[Any, ...], kwargs: dict[str, Any]) -> Any:
    if "port" in kwargs:
        return kwargs["port"]
    return args[0] if args else None


def cell_socket_endpoint(proxy_name: str, port: object = None) -> str:
    """``ARMNET_CELL_SOCKET``, or an error telling the user how to attach a connector."""
    endpoint = os.environ.get(env.CELL_SOCKET, "").strip()
    if endpoint:
        return endpoint
    got = f" (got port={port!r}, which is not a connector endpoint)" if port is not None else ""
    raise ConnectorUnavailable(
        f"{proxy_name} has no cell connector to talk to{got}: pass port=ctx.cell.robot_port "
        f"(a unix:///...robot.sock endpoint) or set {env.CELL_SOCKET}. To drive hardware directly "
        f"from this container instead, set {env.LOCAL_CONTAINER}=1 so LeRobot's own classes stay in place."
    )


class RemoteFeetechMotorsBus(RemoteObjectProxy):
    """Drop-in proxy for LeRobot's ``FeetechMotorsBus``: same constructor, same methods.

    The real bus lives in the connector next to the serial port; ``sync_read``,
    ``sync_write``, ``torque_disabled()`` and the rest are forwarded.
    """

    _remote_class = "FeetechMotorsBus"

    @classmethod
    def _resolve_endpoint(
        cls, args: tuple[Any, ...], kwargs: dict[str, Any]
    ) -> tuple[str, tuple[Any, ...], dict[str, Any]]:
        port = _port_argument(args, kwargs)
        if isinstance(port, str) and looks_like_connector_endpoint(port):
            return port, args, kwargs
        return cell_socket_endpoint(cls.__name__, port), args, kwargs

    @classmethod
    def scan_port(cls, port: str, *args: Any, **kwargs: Any) -> dict[int, list[int]]:
        """The servos of the cell's arm on ``port``, as ``{baudrate: [ids]}`` (``scan_port``'s shape).

        LeRobot probes every baud rate by rewriting the port's line speed; on a
        cell the line speed belongs to the cell, so this asks the arm's bus once,
        at the rate the cell runs it, with a broadcast ping.
        """
        bus = cls(port, {}, *args, **kwargs)
        bus.connect(handshake=False)  # as LeRobot's scan_port: no motors to check yet
        try:
            found = bus.broadcast_ping()
            baudrate = int(bus.default_baudrate)
        finally:
            bus.disconnect(disable_torque=False)
        return {baudrate: sorted(found)} if found else {}

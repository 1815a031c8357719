"""Connector endpoint addresses: parsing and the "is this a connector?" test.

This module owns the grammar of the endpoints written in ``runtime/PROTOCOL.md``
(``unix:///abs.sock``, a bare absolute socket path, ``tcp://host:port``, each with
an optional ``?arm=NAME`` selector). It never opens a socket.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal
from urllib.parse import parse_qs, urlsplit

UNIX_PREFIX = "unix://"
TCP_PREFIX = "tcp://"
#: The connector's two sockets in a job's socket directory (runtime/PROTOCOL.md): the
#: robot (bus and cameras) and the cell operator's (resets, verdicts, teleop, lifecycle).
ROBOT_SOCKET = "robot.sock"
OPERATOR_SOCKET = "operator.sock"
_DEVICE_ROOT = "/dev/"


@dataclass(frozen=True)
class Endpoint:
    """A parsed connector endpoint: where to connect, and which arm it selects."""

    scheme: Literal["unix", "tcp"]
    path: str | None = None
    host: str | None = None
    port: int | None = None
    arm: str | None = None

    @property
    def address(self) -> str:
        """The socket address without the arm selector, for logs and errors."""
        if self.scheme == "unix":
            return f"{UNIX_PREFIX}{self.path}"
        return f"{TCP_PREFIX}{self.host}:{self.port}"


def _arm_from_query(query: str) -> str | None:
    arms = parse_qs(query).get("arm")
    return arms[0] if arms else None


def parse_endpoint(value: str) -> Endpoint:
    """Parse a connector endpoint, or raise ``ValueError`` saying which forms are accepted."""
    text = value.strip()
    if text.startswith(_DEVICE_ROOT):
        raise ValueError(
            f"{value!r} is a device path, not a connector endpoint; a device path means a "
            "local-container run with direct hardware. Use unix:///abs/path.sock or tcp://host:port."
        )
    if text.startswith(TCP_PREFIX):
        parts = urlsplit(text)
        if not parts.hostname or parts.port is None:
            raise ValueError(f"connector endpoint {value!r} needs a host and a port: tcp://host:port")
        return Endpoint("tcp", host=parts.hostname, port=parts.port, arm=_arm_from_query(parts.query))
    if text.startswith(UNIX_PREFIX):
        path, _, query = text[len(UNIX_PREFIX):].partition("?")
    elif text.startswith("/"):
        path, _, query = text.partition("?")
    else:
        raise ValueError(
            f"{value!r} is not a connector endpoint; accepted forms are unix:///abs/path.sock, "
            "/abs/path.sock and tcp://host:port"
        )
    if not path.startswith("/"):
        raise ValueError(f"unix endpoint {value!r} must name an absolute socket path")
    return Endpoint("unix", path=path, arm=_arm_from_query(query))


def looks_like_connector_endpoint(value: str | None) -> bool:
    """True when ``value`` is a connector endpoint rather than a device path or nothing."""
    if not value:
        return False
    try:
        parse_endpoint(value)
    except ValueError:
        return False
    return True


def with_arm(endpoint: str, arm: str) -> str:
    """Return ``endpoint`` selecting ``arm`` (``unix:///run/robot.sock?arm=left``)."""
    base = endpoint.split("?", 1)[0]
    return f"{base}?arm={arm}"

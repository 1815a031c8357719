"""JSON-lines request/reply over a connector endpoint (see runtime/PROTOCOL.md).

This module owns sockets on the SDK side: connecting with a bound, writing one
request line, reading exactly one reply line with a bounded wait, and turning a
``{"ok": false}`` reply into the matching exception. A connection that failed in
any way is closed, so the next request reconnects: a restarted connector, a wedged
peer or a garbage reply costs one call, never the job.
"""

from __future__ import annotations

import builtins
import importlib
import socket
import threading
from typing import Any

from armnet_core.framing import LineReader, LineTooLong

from armnet_runtime.endpoints import Endpoint, parse_endpoint
from armnet_runtime.errors import (
    ConnectorUnavailable,
    InterlockTripped,
    ProtocolError,
    RemoteAttributeError,
    RemoteCallError,
    SafetyViolation,
    ShuttingDown,
)
from armnet_runtime.wire import dumps_line, line_codec, loads_json

CONNECT_TIMEOUT_S = 5.0
"""How long to wait for the connector to accept a connection."""

DEFAULT_CALL_TIMEOUT_S = 30.0
"""How long a hardware call may take before the client gives up on the reply."""

CREATE_TIMEOUT_S = 180.0
"""How long creating a remote device may take: the connector's first ``create`` of a
class imports LeRobot's device module (torch, datasets) unless its warm-up got there
first, and on a busy or small robot host that import alone took over 30 s. The job's own
timeout bounds it all the same; a connector that is gone still fails at once (the socket
closes)."""

REST_TIMEOUT_S = CREATE_TIMEOUT_S
"""How long ``ctx.cell.reset``'s rest move may take: the connector opens the cell's own bus
for it, which, early in a job, waits for the same LeRobot import as a first ``create``
(a loaded host failed a reset at the 30 s call timeout), and then walks every arm at the
cell's rest speed."""

MAX_LINE_BYTES = 64 * 1024 * 1024
"""Longest reply line accepted; matches the connector's request limit."""

_UNSET: Any = object()


# Wire error types re-raised as the built-in exception of the same name, so that
# customer code written against local LeRobot (``except ConnectionError``) keeps working.
_BUILTIN_ERRORS = frozenset(
    {
        "ConnectionError", "RuntimeError", "ValueError", "TimeoutError", "KeyError",
        "TypeError", "IndexError", "OSError", "NotImplementedError", "PermissionError",
    }
)
_LEROBOT_ERRORS = frozenset({"DeviceNotConnectedError", "DeviceAlreadyConnectedError"})
_ARMNET_ERRORS: dict[str, type[RemoteCallError]] = {
    "SafetyViolation": SafetyViolation,
    "InterlockTripped": InterlockTripped,
    "ShuttingDown": ShuttingDown,
}


def _connect(endpoint: Endpoint, timeout: float) -> socket.socket:
    try:
        if endpoint.scheme == "unix":
            sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            sock.settimeout(timeout)
            sock.connect(endpoint.path or "")
        else:
            sock = socket.create_connection((endpoint.host, endpoint.port), timeout=timeout)
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    except OSError as exc:
        raise ConnectorUnavailable(
            f"cannot reach the cell connector at {endpoint.address}: {exc}. "
            "Is the connector running, and is its socket directory mounted into this container?"
        ) from exc
    return sock


class PersistentConnection:
    """One reusable connection to a connector endpoint, safe to share between threads.

    Requests are serialised by a lock because the protocol is strictly
    request/reply per connection.
    """

    def __init__(
        self,
        endpoint: str,
        timeout: float | None = DEFAULT_CALL_TIMEOUT_S,
        *,
        connect_timeout: float = CONNECT_TIMEOUT_S,
    ) -> None:
        self.endpoint = endpoint
        self._address = parse_endpoint(endpoint)
        self._timeout = timeout
        self._connect_timeout = connect_timeout
        self._sock: socket.socket | None = None
        self._sock_timeout: float | None = None
        self._reader: LineReader | None = None  # the lines of ``_sock`` (bytes after a reply stay in it)
        self._lock = threading.Lock()
        self._dumps, self._loads = line_codec()

    def request(self, payload: dict[str, Any], *, timeout: float | None = _UNSET) -> dict[str, Any]:
        """Send one request and return the reply object; raise on transport failure.

        ``timeout`` bounds the wait for the reply (``None`` waits forever; the
        default is the connection's). Any failure closes the connection.
        """
        wait = self._timeout if timeout is _UNSET else timeout
        try:
            line = self._dumps(payload)
        except TypeError:
            line = dumps_line(payload)  # the standard library encodes it, or says precisely why not
        with self._lock:
            try:
                if self._sock is None:
                    self._sock = _connect(self._address, self._connect_timeout)
                    self._sock_timeout = self._connect_timeout
                    self._reader = LineReader(self._sock, MAX_LINE_BYTES)
                if wait != self._sock_timeout:
                    self._sock.settimeout(wait)
                    self._sock_timeout = wait
                self._sock.sendall(line)
                raw = self._read_line(wait)
                try:
                    reply = self._loads(raw)
                except (ValueError, RecursionError):
                    reply = None
                if type(reply) is dict and type(reply.get("ok")) is bool:
                    return reply
                return _parse_reply(raw)  # not a reply: the precise error
            except BaseException:
                self._close_locked()
                raise

    def _read_line(self, wait: float | None) -> bytes:
        """The next reply line without its newline; ConnectorUnavailable if none comes whole."""
        assert self._reader is not None
        try:
            line = self._reader.next()
        except LineTooLong:
            raise ProtocolError(f"reply from {self.endpoint} exceeds {MAX_LINE_BYTES} bytes") from None
        except TimeoutError as exc:
            raise ConnectorUnavailable(f"no reply from the cell connector at {self.endpoint} within {wait} s") from exc
        except OSError as exc:
            raise ConnectorUnavailable(f"connection to {self.endpoint} failed: {exc}") from exc
        if not line.endswith(b"\n"):  # closed, at a line's end or in its middle
            raise ConnectorUnavailable(f"the cell connector at {self.endpoint} closed the connection")
        return line[:-1]

    def close(self) -> None:
        with self._lock:
            self._close_locked()

    def _close_locked(self) -> None:
        if self._sock is not None:
            try:
                self._sock.close()
            finally:
                self._sock = None
                self._sock_timeout = None
                self._reader = None

    def __enter__(self) -> PersistentConnection:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


def _parse_reply(line: bytes) -> dict[str, Any]:
    try:
        reply = loads_json(line)
    except (ValueError, RecursionError) as exc:
        raise ProtocolError(f"connector reply is not JSON: {line[:80]!r}") from exc
    if not isinstance(reply, dict) or not isinstance(reply.get("ok"), bool):
        raise ProtocolError(f"connector reply is not an object with a boolean 'ok': {line[:80]!r}")
    return reply


def connector_request(
    endpoint: str, payload: dict[str, Any], *, read_timeout: float | None = DEFAULT_CALL_TIMEOUT_S
) -> dict[str, Any]:
    """One request on a fresh connection, closed afterwards. Raises on transport failure."""
    with PersistentConnection(endpoint, timeout=read_timeout) as conn:
        return conn.request(payload)


def _lerobot_error(name: str) -> type[Exception] | None:
    try:
        module = importlib.import_module("lerobot.utils.errors")
    except ImportError:
        return None
    found = getattr(module, name, None)
    return found if isinstance(found, type) and issubclass(found, Exception) else None


def error_for_reply(response: dict[str, Any], *, error_message: str) -> Exception:
    """The exception a ``{"ok": false}`` reply stands for, typed by its ``error_type``."""
    error_type = str(response.get("error_type") or "RemoteCallError")
    message = str(response.get("error") or error_message)
    if error_type == "AttributeError":
        return RemoteAttributeError(message)
    if error_type in _ARMNET_ERRORS:
        return _ARMNET_ERRORS[error_type](message, error_type)
    if error_type in _BUILTIN_ERRORS:
        builtin: type[Exception] = getattr(builtins, error_type)
        return builtin(message)
    if error_type in _LEROBOT_ERRORS:
        lerobot_type = _lerobot_error(error_type)
        if lerobot_type is not None:
            return lerobot_type(message)
    return RemoteCallError(f"{error_type}: {message}", error_type)


def check_response(response: dict[str, Any], *, error_message: str) -> dict[str, Any]:
    """Return ``response`` when ``ok``; otherwise raise the exception it stands for."""
    if response.get("ok"):
        return response
    raise error_for_reply(response, error_message=error_message)

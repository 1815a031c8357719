"""The one generic proxy behind every remote LeRobot class (bus, camera, arm).

The connector owns the real object; the customer's container holds a proxy that
forwards attribute reads, writes and method calls over ``robot.sock`` (see
runtime/PROTOCOL.md). LeRobot polls some attributes every control tick, so the
proxy keeps three caches that save round trips without changing semantics:

- method names: whether a name is a method never changes for an object, so the
  ``getattr`` round trip before each call is paid once per name; the method proxy
  is then kept in the instance's ``__dict__``, so a call finds it without
  ``__getattr__`` (a customer's assignment to the name drops it);
- missing names: a name the remote object lacks, or one the connector will not
  hand out (outside its allow-list), stays absent, so ``hasattr`` and
  ``getattr(obj, name, default)`` behave as for a missing attribute and answer
  locally from then on (LeRobot probes optional attributes such as ``use_depth``
  every frame); a *call* the connector refuses is still a clear error;
- ``is_connected``: served locally for :data:`IS_CONNECTED_TTL_S` after the proxy
  learned it (a read, ``connect()`` or ``disconnect()``), so staleness is bounded.

A dropped connection (a restarted connector) costs at most one call: the next
request opens a new connection, re-creates the remote object with the original
constructor arguments and, when it had been connected, replays ``connect()``.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any, ClassVar, TypeVar

from armnet_runtime.errors import (
    ConnectorUnavailable,
    ProtocolError,
    RemoteAttributeError,
    RemoteCallError,
)
from armnet_runtime.transport import (
    CREATE_TIMEOUT_S,
    DEFAULT_CALL_TIMEOUT_S,
    PersistentConnection,
    check_response,
)
from armnet_runtime.wire import decode, encode, encode_items

logger = logging.getLogger("armnet_runtime.lerobot")

_T = TypeVar("_T")

IS_CONNECTED_TTL_S = 0.5
"""How long a known ``is_connected`` value is served without asking the connector."""


class _UnsentRequest(Exception):
    """Internal: writing a request failed, so the connector never saw it."""


class DeviceRefused(RemoteCallError, ConnectionError):
    """The connector refused the port or device a constructor named (not this cell's).

    A ``ConnectionError``, as LeRobot raises when a port or camera cannot be opened,
    so code written against a bare arm (``except ConnectionError``) keeps working.
    """


NOT_ALLOWED = "NotAllowed"
"""The wire error type of a request outside the connector's allow-list."""


class ReadOnlyView:
    """Plain values the connector reports about a hardware helper (``bus.port_handler``).

    LeRobot code reads a few facts from the bus's port and packet handlers; the
    handlers themselves drive the serial line and never leave the connector. This
    view holds a snapshot of their safe values, taken when the attribute was read.
    """

    __slots__ = ("_name", "_values")

    def __init__(self, name: str, values: dict[str, Any]) -> None:
        object.__setattr__(self, "_name", name)
        object.__setattr__(self, "_values", dict(values))

    def __getattr__(self, name: str) -> Any:
        values: dict[str, Any] = object.__getattribute__(self, "_values")
        if name in values:
            return values[name]
        raise RemoteAttributeError(
            f"{object.__getattribute__(self, '_name')}.{name} is not available through the cell connector; "
            f"it reports {sorted(values)}"
        )

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError(f"{self._name} is a read-only view of the connector's {self._name}")

    def __repr__(self) -> str:
        return f"<read-only {self._name} {self._values!r}>"


def encode_args(args: tuple[Any, ...]) -> list[Any]:
    """Positional arguments as the JSON list the protocol's ``args`` field carries."""
    return encode_items(args)


class RemoteContextManager:
    """A context manager that lives on the connector (e.g. ``bus.torque_disabled()``).

    ``with`` drives it with the protocol's ``enter``/``exit`` ops; the exception
    raised inside the block travels as its type name and message, and the remote
    ``__exit__`` decides whether it is suppressed.
    """

    def __init__(
        self,
        conn: PersistentConnection,
        object_id: str,
        *,
        error_message: str = "remote context manager failed",
        owner: RemoteObjectProxy | None = None,
    ) -> None:
        self._conn = conn
        self._object_id = object_id
        self._error_message = error_message
        self._owner = owner

    def _raw(self, payload: dict[str, Any]) -> dict[str, Any]:
        # Through the owner so a lost connection marks its remote object as lost too.
        return self._owner._transport(payload) if self._owner is not None else self._conn.request(payload)

    def __enter__(self) -> Any:
        reply = self._raw({"op": "enter", "object_id": self._object_id})
        return decode(check_response(reply, error_message=self._error_message).get("value"))

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: object) -> bool:
        reply = self._raw(
            {
                "op": "exit",
                "object_id": self._object_id,
                "exc_type": exc_type.__name__ if exc_type is not None else None,
                "exc_message": str(exc) if exc is not None else None,
            }
        )
        return bool(check_response(reply, error_message=self._error_message).get("suppress"))

    def __repr__(self) -> str:
        return f"<RemoteContextManager {self._object_id} at {self._conn.endpoint}>"


class RemoteObjectProxy:
    """Forwards a LeRobot object's public surface to the connector that owns the real one.

    Subclasses name the allow-listed remote class and say where the endpoint comes
    from; everything else is shared. Private and dunder names are never forwarded.
    """

    _remote_class: ClassVar[str] = ""
    _call_timeout_s: ClassVar[float | None] = DEFAULT_CALL_TIMEOUT_S

    _endpoint: str
    _conn: PersistentConnection
    _object_id: str | None
    _create_args: list[Any]
    _create_kwargs: Any
    _methods: dict[str, Callable[..., Any]]
    _missing: dict[str, str]
    _connected: bool | None
    _connected_at: float
    _connect_call: tuple[tuple[Any, ...], dict[str, Any]] | None
    _stale: bool
    _lock: threading.RLock

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        endpoint, args, kwargs = self._resolve_endpoint(args, kwargs)
        init = object.__setattr__
        init(self, "_endpoint", endpoint)
        init(self, "_conn", PersistentConnection(endpoint, timeout=self._call_timeout_s))
        init(self, "_object_id", None)
        init(self, "_create_args", encode_args(args))
        init(self, "_create_kwargs", encode(kwargs))
        init(self, "_methods", {})
        init(self, "_missing", {})
        init(self, "_connected", None)
        init(self, "_connected_at", 0.0)
        init(self, "_connect_call", None)
        init(self, "_stale", False)
        init(self, "_lock", threading.RLock())
        logger.info("%s: creating the remote %s at %s", type(self).__name__, self._remote_class, endpoint)
        self._with_retry(lambda: None)

    # ------------------------------------------------------------------ subclass hooks

    @classmethod
    def _resolve_endpoint(
        cls, args: tuple[Any, ...], kwargs: dict[str, Any]
    ) -> tuple[str, tuple[Any, ...], dict[str, Any]]:
        """Return (endpoint, args, kwargs to send to ``create``)."""
        raise NotImplementedError

    # ------------------------------------------------------------------ requests

    def _transport(self, payload: dict[str, Any], timeout: float | None = None) -> dict[str, Any]:
        """One request/reply (waiting ``timeout``, or the class's call timeout); any
        transport failure marks the remote object as lost."""
        try:
            if timeout is None:
                return self._conn.request(payload)
            return self._conn.request(payload, timeout=timeout)
        except (ConnectorUnavailable, ProtocolError):
            object.__setattr__(self, "_stale", True)
            raise
        except OSError as exc:
            # Raised while writing (reads are wrapped in ConnectorUnavailable):
            # the connector never saw the request, so it is safe to send again.
            object.__setattr__(self, "_stale", True)
            raise _UnsentRequest(str(exc)) from exc

    def _send(self, payload: dict[str, Any], timeout: float | None = None) -> dict[str, Any]:
        reply = self._transport(payload, timeout)
        if reply.get("ok"):
            return reply  # the usual reply: no failure message to build
        return check_response(reply, error_message=f"remote {self._remote_class} {payload['op']} failed")

    def _create(self) -> None:
        try:
            reply = self._send(
                {"op": "create", "class": self._remote_class, "args": self._create_args, "kwargs": self._create_kwargs},
                # The connector may still be importing the class's LeRobot module (transport.py).
                timeout=None if self._call_timeout_s is None else max(CREATE_TIMEOUT_S, self._call_timeout_s),
            )
        except RemoteCallError as exc:
            if exc.error_type != NOT_ALLOWED:
                raise
            raise DeviceRefused(str(exc), exc.error_type) from None
        object_id = reply.get("object_id")
        if not isinstance(object_id, str):
            raise ProtocolError(f"connector reply to create has no string object_id: {reply!r}"[:200])
        object.__setattr__(self, "_object_id", object_id)
        object.__setattr__(self, "_stale", False)

    def _recover(self) -> None:
        """Re-create the remote object on a fresh connection (and re-connect it if it was)."""
        logger.warning(
            "%s: the connection to %s was lost; re-creating the remote %s",
            type(self).__name__, self._endpoint, self._remote_class,
        )
        self._create()
        replay = self._connect_call
        if replay is not None:
            args, kwargs = replay
            self._send(
                {
                    "op": "call", "object_id": self._object_id, "method": "connect",
                    "args": encode_args(args), "kwargs": encode(kwargs),
                }
            )

    def _with_retry(self, action: Callable[[], _T], *, first_attempt: int = 1) -> _T:
        with self._lock:
            for attempt in range(first_attempt, 3):
                try:
                    if self._object_id is None:
                        self._create()
                    elif self._stale:
                        self._recover()
                    return action()
                except _UnsentRequest as exc:
                    if attempt == 2:
                        raise ConnectorUnavailable(
                            f"cannot send to the cell connector at {self._endpoint}: {exc}"
                        ) from exc.__cause__
            raise AssertionError("unreachable")

    def _request(self, payload: dict[str, Any]) -> dict[str, Any]:
        """Send an op on this object; ``object_id`` is filled in at send time."""
        return self._with_retry(self._send_call(payload))

    # ------------------------------------------------------------------ attribute protocol

    def _set_connected(self, value: bool) -> None:
        object.__setattr__(self, "_connected", value)
        object.__setattr__(self, "_connected_at", time.monotonic())

    def __getattr__(self, name: str) -> Any:
        if name.startswith("_"):
            raise AttributeError(name)
        if name == "is_connected":
            known = self._connected
            if known is not None and time.monotonic() - self._connected_at < IS_CONNECTED_TTL_S:
                return known
        method = self._methods.get(name)
        if method is not None:
            return method
        why = self._missing.get(name)
        if why is not None:
            raise RemoteAttributeError(why)
        try:
            reply = self._request({"op": "getattr", "name": name})
        except AttributeError as exc:
            self._missing[name] = str(exc) or f"remote {self._remote_class} has no attribute {name!r}"
            raise
        except RemoteCallError as exc:
            if exc.error_type != NOT_ALLOWED:
                raise
            # Out of reach is absent, as far as Python's attribute protocol goes.
            self._missing[name] = str(exc)
            raise RemoteAttributeError(str(exc)) from None
        if reply.get("callable"):
            method = self._method_proxy(name)
            self._methods[name] = method
            self.__dict__[name] = method  # found by plain attribute lookup from now on
            return method
        value = decode(reply.get("value"))
        if reply.get("view") and isinstance(value, dict):
            return ReadOnlyView(name, value)
        if name == "is_connected":
            self._set_connected(bool(value))
        return value

    def __setattr__(self, name: str, value: Any) -> None:
        if name.startswith("_"):
            object.__setattr__(self, name, value)
            return
        self._request({"op": "setattr", "name": name, "value": encode(value)})
        self._missing.pop(name, None)
        if self._methods.pop(name, None) is not None:
            self.__dict__.pop(name, None)

    def _call(self, payload: dict[str, Any]) -> dict[str, Any]:
        """``_request`` for a call on a live object, without its closures; anything unusual takes ``_request``.

        Why: a control loop calls a few methods at 100 Hz on an object that exists
        and a connection that works; creating, recovering and resending are for the
        other calls. A send that failed here (the connector never saw it; ``_transport``
        marked the object lost) continues as ``_request``'s second attempt: re-create, send again.
        """
        with self._lock:
            object_id = self._object_id
            if object_id is not None and not self._stale:
                payload["object_id"] = object_id
                try:
                    return self._send(payload)
                except _UnsentRequest:
                    return self._with_retry(self._send_call(payload), first_attempt=2)
        return self._request(payload)

    def _send_call(self, payload: dict[str, Any]) -> Callable[[], dict[str, Any]]:
        return lambda: self._send({**payload, "object_id": self._object_id})

    def _method_proxy(self, name: str) -> Callable[..., Any]:
        lifecycle = name in ("connect", "disconnect")

        def method(*args: Any, **kwargs: Any) -> Any:
            reply = self._call(
                {"op": "call", "method": name, "args": encode_args(args), "kwargs": encode(kwargs) if kwargs else {}}
            )
            if lifecycle:
                self._lifecycle(name, args, kwargs)
            if reply.get("context_manager"):
                object_id = reply.get("object_id")
                if not isinstance(object_id, str):
                    raise ProtocolError(f"context-manager reply has no string object_id: {reply!r}"[:200])
                return RemoteContextManager(
                    self._conn, object_id, error_message=f"remote {self._remote_class}.{name}() failed", owner=self
                )
            value = reply.get("value")
            return None if value is None else decode(value)

        method.__name__ = name
        method.__qualname__ = f"{type(self).__name__}.{name}"
        return method

    def _lifecycle(self, name: str, args: tuple[Any, ...], kwargs: dict[str, Any]) -> None:
        """After ``connect()``/``disconnect()``: what the proxy knows of the connection, and what a recovery replays."""
        connected = name == "connect"
        self._set_connected(connected)
        object.__setattr__(self, "_connect_call", (args, kwargs) if connected else None)

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self._object_id} at {self._endpoint}>"

    def __del__(self) -> None:
        conn = self.__dict__.get("_conn")
        if conn is not None:
            conn.close()

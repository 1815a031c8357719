"""The connector's object ops over plain Python objects, for testing the SDK's remote proxies.

Built on :class:`tests.support.jsonl_server.JsonlServer` (a real unix-socket
JSON-lines peer). It serves the ``robot.sock`` object ops of runtime/PROTOCOL.md
(``hello``, ``create``, ``getattr``, ``setattr``, ``call``, ``enter``, ``exit``,
``close``) over objects built from the factories a test hands it, and counts
every request so tests can assert what the client's caches saved. Like the
connector, it forgets every object when it stops; it can also be wedged (reads
requests, never answers) or made to answer garbage.
"""

from __future__ import annotations

import builtins
import contextlib
import itertools
import threading
from collections.abc import Callable, Iterator
from typing import Any

from armnet_runtime.wire import decode, encode

from tests.support.jsonl_server import WEDGE, JsonlServer


class _Failure(Exception):
    def __init__(self, error_type: str, message: str) -> None:
        super().__init__(message)
        self.error_type = error_type


class ObjectServer:
    """Serves objects built by ``factories[class_name](*args, **kwargs)`` on ``path``."""

    def __init__(self, path: str, factories: dict[str, Callable[..., Any]]) -> None:
        self.factories = factories
        self.created: list[Any] = []
        self.mode = "normal"  # "normal" | "wedge" | "garbage"
        self.garbage = b"this is not json\n"
        self._objects: dict[str, Any] = {}
        self._ids = itertools.count(1)
        self._lock = threading.Lock()
        self._server = JsonlServer(path, self._handle)

    @property
    def path(self) -> str:
        return self._server.path

    @property
    def endpoint(self) -> str:
        return self._server.endpoint

    @property
    def requests(self) -> list[dict[str, Any]]:
        return self._server.requests

    def start(self) -> ObjectServer:
        self._server.start()
        return self

    def stop(self) -> None:
        """Close the listener and every connection and forget all objects, as a crashed connector would."""
        self._server.stop()
        with self._lock:
            self._objects.clear()

    def restart(self) -> None:
        self.stop()
        self.start()

    def __enter__(self) -> ObjectServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def count(self, op: str, name: str | None = None) -> int:
        """How many ``op`` requests (for attribute/method ``name``, if given) arrived."""
        return sum(
            1
            for request in list(self.requests)
            if request.get("op") == op and (name is None or (request.get("name") or request.get("method")) == name)
        )

    def _handle(self, request: dict[str, Any]) -> Any:
        if self.mode == "wedge":
            return WEDGE
        if self.mode == "garbage":
            return self.garbage
        try:
            with self._lock:
                return {"ok": True, **self._dispatch(request, self._objects)}
        except _Failure as exc:
            return {"ok": False, "error": str(exc), "error_type": exc.error_type}
        except Exception as exc:  # noqa: BLE001 - the real call's error travels by name
            return {"ok": False, "error": str(exc), "error_type": type(exc).__name__}

    def _dispatch(self, request: dict[str, Any], objects: dict[str, Any]) -> dict[str, Any]:
        op = request.get("op")
        if op == "hello":
            return {"protocol": 1, "server": "test-object-server", "socket": "robot"}
        if op == "create":
            factory = self.factories.get(request.get("class", ""))
            if factory is None:
                raise _Failure("NotAllowed", f"class {request.get('class')!r} is not allowed")
            obj = factory(*decode(request.get("args", [])), **decode(request.get("kwargs", {})))
            self.created.append(obj)
            return {"object_id": self._store(objects, obj)}
        target = objects.get(request.get("object_id", ""))
        if target is None:
            raise _Failure("UnknownObject", f"no object {request.get('object_id')!r} on this connection")
        if op == "getattr":
            value = getattr(target, self._public(request["name"]))
            if callable(value):
                return {"callable": True}
            return {"callable": False, "value": encode(value)}
        if op == "setattr":
            setattr(target, self._public(request["name"]), decode(request["value"]))
            return {}
        if op == "call":
            method = getattr(target, self._public(request["method"]))
            result = method(*decode(request.get("args", [])), **decode(request.get("kwargs", {})))
            if hasattr(result, "__enter__") and hasattr(result, "__exit__"):
                return {"context_manager": True, "object_id": self._store(objects, result)}
            return {"value": encode(result)}
        if op == "enter":
            return {"value": encode(target.__enter__())}
        if op == "exit":
            exc_type = getattr(builtins, request.get("exc_type") or "", None)
            exc = exc_type(request.get("exc_message")) if isinstance(exc_type, type) else None
            suppress = target.__exit__(type(exc) if exc else None, exc, None)
            return {"suppress": bool(suppress)}
        if op == "close":
            objects.pop(request.get("object_id", ""), None)
            return {}
        raise _Failure("UnknownOp", f"op {op!r} is not served")

    def _store(self, objects: dict[str, Any], obj: Any) -> str:
        object_id = f"o{next(self._ids)}"
        objects[object_id] = obj
        return object_id

    @staticmethod
    def _public(name: str) -> str:
        if name.startswith("_"):
            raise _Failure("NotAllowed", f"attribute {name!r} is private")
        return name


@contextlib.contextmanager
def serving(path: str, factories: dict[str, Callable[..., Any]]) -> Iterator[ObjectServer]:
    server = ObjectServer(path, factories).start()
    try:
        yield server
    finally:
        server.stop()

"""A small threaded JSON-lines server on a unix socket, for testing clients of the connector protocol.

A test hands it a ``handler(request) -> reply``; the reply may be a dict (sent as
one JSON line), raw ``bytes`` (sent as is: garbage replies), :data:`WEDGE`
(read the request, never answer: a wedged peer) or :data:`HANG_UP` (close the
connection). Every request is recorded in order. The server can be stopped and
started again on the same path to test reconnects. It is a real socket peer:
nothing in the client is mocked.
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
import threading
from collections.abc import Callable
from typing import Any

WEDGE = object()
HANG_UP = object()

Handler = Callable[[dict[str, Any]], Any]


class JsonlServer:
    """Serves ``handler`` on ``path`` (one thread per connection), recording requests."""

    def __init__(self, path: str, handler: Handler) -> None:
        self.path = path
        self.handler = handler
        self.requests: list[dict[str, Any]] = []
        self.connections = 0
        self._lock = threading.Lock()
        self._release = threading.Event()
        self._listener: socket.socket | None = None
        self._conns: list[socket.socket] = []
        self._threads: list[threading.Thread] = []

    @property
    def endpoint(self) -> str:
        return f"unix://{self.path}"

    def ops(self) -> list[str]:
        with self._lock:
            return [str(request.get("op")) for request in self.requests]

    def start(self) -> JsonlServer:
        if os.path.exists(self.path):
            os.unlink(self.path)
        self._release.clear()
        listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        listener.bind(self.path)
        listener.listen(16)
        self._listener = listener
        thread = threading.Thread(target=self._accept_loop, args=(listener,), daemon=True)
        thread.start()
        self._threads.append(thread)
        return self

    def stop(self) -> None:
        """Close the listener and every connection; wedged handlers are released."""
        self._release.set()
        if self._listener is not None:
            with contextlib.suppress(OSError):
                self._listener.shutdown(socket.SHUT_RDWR)
            self._listener.close()
            self._listener = None
        with self._lock:
            conns, self._conns = self._conns, []
        for conn in conns:
            with contextlib.suppress(OSError):
                conn.shutdown(socket.SHUT_RDWR)
            conn.close()
        for thread in self._threads:
            thread.join(timeout=5)
        self._threads = []
        with contextlib.suppress(FileNotFoundError):
            os.unlink(self.path)

    def __enter__(self) -> JsonlServer:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    def _accept_loop(self, listener: socket.socket) -> None:
        while True:
            try:
                conn, _ = listener.accept()
            except OSError:
                return
            with self._lock:
                self._conns.append(conn)
                self.connections += 1
            thread = threading.Thread(target=self._serve, args=(conn,), daemon=True)
            thread.start()
            self._threads.append(thread)

    def _serve(self, conn: socket.socket) -> None:
        reader = conn.makefile("rb")
        try:
            for line in reader:
                request = json.loads(line)
                with self._lock:
                    self.requests.append(request)
                reply = self.handler(request)
                if reply is WEDGE:
                    self._release.wait()
                    return
                if reply is HANG_UP:
                    return
                data = reply if isinstance(reply, bytes) else json.dumps(reply).encode() + b"\n"
                conn.sendall(data)
        except (OSError, ValueError):
            return
        finally:
            with contextlib.suppress(OSError):
                reader.close()
                conn.close()

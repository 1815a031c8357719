"""JSON-lines over a unix socket: one thread per connection, blocking I/O.

This module owns framing and connection lifetimes: it reads one request line
(at most ``MAX_LINE_BYTES``), hands the parsed object to the connection's
session and writes one reply line. A thread per connection with blocking I/O
keeps the hot path to a ``recv``, a JSON decode, the call, a JSON encode and
``sendall`` (no buffered file object: its Python layers cost measurably on a
control loop's cold caches, see bench/proxy_overhead.py). It never interprets an op.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import socket
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from armnet_runtime.wire import dumps_line, loads_json

from .errors import RequestError, protocol_error
from .session import Session

log = logging.getLogger(__name__)

MAX_LINE_BYTES = 64 * 1024 * 1024
_ACCEPT_POLL_S = 0.2
_RECV_CHUNK = 1 << 16



def encode_reply(reply: dict[str, Any]) -> bytes:
    try:
        return dumps_line(reply)  # orjson when installed (armnet_runtime.wire)
    except (TypeError, ValueError) as exc:  # a session bug must still produce a well-formed reply
        text = json.dumps({"ok": False, "error": f"reply could not be encoded: {exc}", "error_type": "RuntimeError"})
    return text.encode() + b"\n"


def parse_request(line: bytes) -> dict[str, Any]:
    """The request object of one line; ``RequestError(ProtocolError)`` when it is not one."""
    try:
        request = loads_json(line)
    except (ValueError, RecursionError) as exc:
        raise protocol_error(f"the request line is not JSON ({exc}); send one JSON object per line") from None
    if not isinstance(request, dict):
        raise protocol_error(f"a request must be a JSON object, got {type(request).__name__}")
    return request


class LineReader:
    """Newline-framed lines from a blocking socket, read with plain ``recv``.

    ``next()`` returns a line with its newline; or, when the peer closed or a line
    outgrew ``limit``, whatever is left without one (empty at a clean close).
    """

    def __init__(self, conn: socket.socket, limit: int = MAX_LINE_BYTES) -> None:
        self._conn = conn
        self._limit = limit
        self._buffer = bytearray()

    def next(self) -> bytes:
        if not self._buffer:
            chunk = self._conn.recv(_RECV_CHUNK)
            if chunk.find(b"\n") == len(chunk) - 1:
                return chunk  # the usual case: one whole request per chunk (or b"" at close)
            self._buffer += chunk
        while True:
            end = self._buffer.find(b"\n")
            if end >= 0:
                line = bytes(self._buffer[: end + 1])
                del self._buffer[: end + 1]
                return line
            if len(self._buffer) > self._limit:
                return bytes(self._buffer)
            chunk = self._conn.recv(_RECV_CHUNK)
            if not chunk:
                rest = bytes(self._buffer)
                self._buffer.clear()
                return rest
            self._buffer += chunk


class UnixServer:
    """Serves one unix socket; each connection gets its own thread and ``Session``."""

    def __init__(self, path: Path, session_factory: Callable[[], Session], on_connect: Callable[[], None]) -> None:
        self.path = Path(path)
        self._session_factory = session_factory
        self._on_connect = on_connect
        self._listener: socket.socket | None = None
        self._stop = threading.Event()
        self._accept_thread: threading.Thread | None = None
        self._connections: dict[int, tuple[socket.socket, threading.Thread]] = {}
        self._lock = threading.Lock()

    def start(self) -> None:
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()
        listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        listener.bind(str(self.path))
        os.chmod(self.path, 0o666)  # the job container may run as another uid
        listener.listen(64)
        listener.settimeout(_ACCEPT_POLL_S)
        self._listener = listener
        self._accept_thread = threading.Thread(target=self._accept_loop, name=f"armnet-accept-{self.path.name}", daemon=True)
        self._accept_thread.start()

    def _accept_loop(self) -> None:
        assert self._listener is not None
        while not self._stop.is_set():
            try:
                conn, _ = self._listener.accept()
            except TimeoutError:
                continue
            except OSError:
                if self._stop.is_set():
                    return
                log.exception("accept failed on %s", self.path)
                continue
            conn.settimeout(None)
            self._on_connect()
            thread = threading.Thread(target=self._serve, args=(conn,), name=f"armnet-conn-{self.path.name}", daemon=True)
            with self._lock:
                self._connections[id(conn)] = (conn, thread)
            thread.start()

    def _serve(self, conn: socket.socket) -> None:
        session = self._session_factory()
        try:
            reader = LineReader(conn)
            while not self._stop.is_set():
                line = reader.next()
                if not line:
                    return
                if not line.endswith(b"\n"):
                    if len(line) > MAX_LINE_BYTES:
                        reply = protocol_error(
                            f"request line longer than {MAX_LINE_BYTES} bytes; the connection is closed"
                        ).reply()
                        conn.sendall(encode_reply(reply))
                    return  # oversized (cannot resync) or the client closed mid-line
                try:
                    request = parse_request(line)
                except RequestError as exc:
                    reply = exc.reply()
                else:
                    reply = session.handle(request)
                conn.sendall(encode_reply(reply))
        except OSError as exc:
            log.debug("connection on %s ended: %s", self.path.name, exc)
        finally:
            session.close()
            with self._lock:
                self._connections.pop(id(conn), None)
            with contextlib.suppress(OSError):
                conn.close()

    def stop(self) -> None:
        self._stop.set()
        if self._listener is not None:
            with contextlib.suppress(OSError):
                self._listener.shutdown(socket.SHUT_RDWR)  # wakes accept() at once on Linux
            with contextlib.suppress(OSError):
                self._listener.close()
        if self._accept_thread is not None:
            self._accept_thread.join(timeout=2)
        with self._lock:
            connections = list(self._connections.values())
        for conn, _ in connections:
            with contextlib.suppress(OSError):
                conn.shutdown(socket.SHUT_RDWR)
        for _, thread in connections:
            thread.join(timeout=5)
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()

"""JSON-lines over a unix socket: one thread per connection, blocking I/O.

This module owns connection lifetimes: it reads one request line (at most
``MAX_LINE_BYTES``, cut by ``armnet_core.framing``, the one JSON-lines framing),
hands the parsed object to the connection's session and writes one reply line.
A thread per connection with blocking I/O keeps the hot path to a ``recv``, a
JSON decode, the call, a JSON encode and ``sendall`` (no buffered file object:
its Python layers cost measurably on a control loop's cold caches, see
bench/proxy_overhead.py). It never interprets an op.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from armnet_core.backoff import BackoffPolicy
from armnet_core.framing import BudgetExhausted, BufferBudget, FramingError, LineReader, LineTooLong
from armnet_runtime.wire import dumps_line, line_codec

from .cell import Counters
from .errors import RequestError, protocol_error
from .ratelog import RateLimitedLog
from .session import Session

log = logging.getLogger(__name__)

MAX_LINE_BYTES = 1 << 20
"""A request line is control traffic (calls, small arguments): 1 MiB is far above
any real one. Frames never travel in requests (replies carry them, by the data plane)."""
MAX_BUFFERED_BYTES = 32 << 20
"""Unfinished request lines held across every connection of one connector."""
MAX_CONNECTIONS = 64
"""Connections per socket; a job needs a handful (one per thread or process)."""
_ACCEPT_POLL_S = 0.2
#: ``accept`` failing (out of file descriptors): retried after 10 ms, doubling, at most 1 s apart.
_ACCEPT_BACKOFF = BackoffPolicy(first_s=0.01, max_s=1.0)
_REFUSAL_SEND_TIMEOUT_S = 0.5
_STOP_JOIN_S = 3.0  # stop() waits this long in all for the threads of one socket


@dataclass(frozen=True)
class ServerLimits:
    """What one socket accepts; every value bounds what a hostile peer can make it hold."""

    max_connections: int = MAX_CONNECTIONS
    max_line_bytes: int = MAX_LINE_BYTES


#: The line codec, bound once (``armnet_runtime.wire.line_codec``: orjson's C functions when installed).
_dumps, _loads = line_codec()


def encode_reply(reply: dict[str, Any]) -> bytes:
    try:
        try:
            return _dumps(reply)
        except TypeError:
            return dumps_line(reply)  # the standard library encodes it, or says precisely why not
    except (TypeError, ValueError) as exc:  # a session bug must still produce a well-formed reply
        text = json.dumps({"ok": False, "error": f"reply could not be encoded: {exc}", "error_type": "RuntimeError"})
    return text.encode() + b"\n"


def parse_request(line: bytes) -> dict[str, Any]:
    """The request object of one line; ``RequestError(ProtocolError)`` when it is not one."""
    try:
        request = _loads(line)
    except (ValueError, RecursionError) as exc:
        raise protocol_error(f"the request line is not JSON ({exc}); send one JSON object per line") from None
    if not isinstance(request, dict):
        raise protocol_error(f"a request must be a JSON object, got {type(request).__name__}")
    return request


def framing_message(error: FramingError) -> str:
    """What the job is told when its bytes cannot be framed; the connection closes after it."""
    if isinstance(error, LineTooLong):
        return (
            f"request line longer than {error.limit} bytes; the connection is closed "
            "(requests are small control messages: camera frames come back by the data plane)"
        )
    if isinstance(error, BudgetExhausted):
        return (
            "the connector is holding too many unfinished request lines; this connection is closed "
            "(finish each request line with a newline)"
        )
    return f"{error}; the connection is closed"


class UnixServer:
    """Serves one unix socket; each connection gets its own thread and ``Session``.

    The accept loop survives every error: a failed ``accept`` (say at the
    descriptor limit) backs off and is logged at most once per interval; a
    connection over the cap, or one no thread can be started for, gets one
    error line and is closed.
    """

    def __init__(
        self,
        path: Path,
        session_factory: Callable[[], Session],
        counters: Counters,
        *,
        limits: ServerLimits | None = None,
        budget: BufferBudget | None = None,
    ) -> None:
        self.path = Path(path)
        self._session_factory = session_factory
        self._counters = counters
        self._limits = limits if limits is not None else ServerLimits()
        self._budget = budget if budget is not None else BufferBudget(MAX_BUFFERED_BYTES)
        self._listener: socket.socket | None = None
        self._stop = threading.Event()
        self._stopping = False  # the same as ``_stop.is_set()``, read per request without a call
        self._accept_thread: threading.Thread | None = None
        self._connections: dict[int, tuple[socket.socket, threading.Thread]] = {}
        self._lock = threading.Lock()
        self._accept_log = RateLimitedLog(log)
        self._refusal_log = RateLimitedLog(log)

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
        backoff = _ACCEPT_BACKOFF.start()
        while not self._stop.is_set():
            try:
                conn, _ = self._listener.accept()
            except TimeoutError:
                continue
            except OSError as exc:
                if self._stop.is_set():
                    return
                self._counters.accept_errors += 1
                delay = backoff.failed()
                self._accept_log.warning("accept on %s failed (%s); retrying in %.2f s", self.path.name, exc, delay)
                self._stop.wait(delay)
                continue
            backoff.succeeded()
            try:
                self._admit(conn)
            except Exception as exc:  # noqa: BLE001 — nothing a peer does may end the accept loop
                self._accept_log.warning("could not serve a connection on %s: %r", self.path.name, exc)
                with contextlib.suppress(OSError):
                    conn.close()

    def _admit(self, conn: socket.socket) -> None:
        conn.settimeout(None)
        thread = threading.Thread(target=self._serve, args=(conn,), name=f"armnet-conn-{self.path.name}", daemon=True)
        with self._lock:
            if len(self._connections) >= self._limits.max_connections:
                refusal = (
                    f"{self.path.name} already serves {self._limits.max_connections} connections, its limit; "
                    "close connections you no longer use (one per thread or process is enough)"
                )
            else:
                self._connections[id(conn)] = (conn, thread)
                refusal = None
        if refusal is None:
            self._counters.connections += 1
            try:
                thread.start()
                return
            except RuntimeError as exc:  # "can't start new thread": the host's thread limit
                with self._lock:
                    self._connections.pop(id(conn), None)
                refusal = f"the connector cannot start a thread for this connection ({exc}); retry later"
        self._counters.connections_refused += 1
        self._refusal_log.warning("refused a connection on %s: %s", self.path.name, refusal)
        self._refuse(conn, refusal)

    @staticmethod
    def _refuse(conn: socket.socket, message: str) -> None:
        reply = {"ok": False, "error": message, "error_type": "TooManyConnections"}
        with contextlib.suppress(OSError):
            conn.settimeout(_REFUSAL_SEND_TIMEOUT_S)
            conn.sendall(encode_reply(reply))
        with contextlib.suppress(OSError):
            conn.close()

    def _serve(self, conn: socket.socket) -> None:
        session: Session | None = None
        reader = LineReader(conn, self._limits.max_line_bytes, self._budget)
        try:
            session = self._session_factory()
            while not self._stopping:
                try:
                    line = reader.next()
                except FramingError as exc:
                    self._counters.oversized_requests += 1
                    conn.sendall(encode_reply(protocol_error(framing_message(exc)).reply()))
                    return
                if not line.endswith(b"\n"):
                    return  # the client closed, at a line's end or in its middle
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
            reader.close()
            if session is not None:
                session.close()
            with self._lock:
                self._connections.pop(id(conn), None)
            with contextlib.suppress(OSError):
                conn.close()

    def stop(self) -> None:
        """Stop accepting, end every connection; waits at most a few seconds in all."""
        self.shut()
        self.join(time.monotonic() + _STOP_JOIN_S)

    def shut(self) -> None:
        """Stop accepting and cut every connection, without waiting for their threads."""
        self._stopping = True
        self._stop.set()
        if self._listener is not None:
            with contextlib.suppress(OSError):
                self._listener.shutdown(socket.SHUT_RDWR)  # wakes accept() at once on Linux
            with contextlib.suppress(OSError):
                self._listener.close()
        with self._lock:
            connections = list(self._connections.values())
        for conn, _ in connections:
            with contextlib.suppress(OSError):
                conn.shutdown(socket.SHUT_RDWR)
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()

    def join(self, deadline: float) -> None:
        """Wait for the accept and connection threads until ``deadline`` (``time.monotonic``).

        A thread still in a bus call at the deadline is left to finish on its
        own (daemon): the interlock already refuses motion, and the cell's
        release turns torque off under the device lock's own deadline.
        """
        threads = [self._accept_thread] if self._accept_thread is not None else []
        with self._lock:
            threads += [thread for _, thread in self._connections.values()]
        for thread in threads:
            thread.join(timeout=max(0.0, deadline - time.monotonic()))

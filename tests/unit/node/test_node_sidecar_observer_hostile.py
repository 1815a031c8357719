"""The agent's client of a pod's observer socket against a hostile peer in the connector's place.

Whoever could write into the observer volume (it is the connector's only, but the
agent must not depend on that alone) might put a symlink where the socket was, or
serve a socket of its own that trickles, nests or never answers. None of that may
hold the agent's job runner or point it at another pod's socket.
"""

from __future__ import annotations

import os
import socket
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from armnet_node.metrics import AgentMetrics
from armnet_node.sidecar_observer import SidecarObserver
from armnet_node.sidecar_socket import connect_long

pytestmark = pytest.mark.unit


@pytest.fixture
def peer(tmp_path: Path) -> Iterator[Callable[[Callable[[socket.socket], None]], Path]]:
    """A unix socket server at ``tmp_path/observer.sock`` that answers every connection with ``serve``."""
    servers: list[socket.socket] = []

    def start(serve: Callable[[socket.socket], None]) -> Path:
        path = tmp_path / "observer.sock"
        server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        server.bind(str(path))
        server.listen()
        servers.append(server)

        def accept() -> None:
            while True:
                try:
                    conn, _ = server.accept()
                except OSError:
                    return
                threading.Thread(target=serve, args=(conn,), daemon=True).start()

        threading.Thread(target=accept, daemon=True).start()
        return path

    yield start
    for server in servers:
        server.close()


def failures(metrics: AgentMetrics, result: str) -> float:
    return metrics.observer_requests.labels(result=result)._value.get()


def test_a_symlink_in_the_sockets_place_is_not_followed(tmp_path: Path, peer) -> None:
    elsewhere = peer(lambda conn: conn.sendall(b'{"ok": true, "servos": null}\n'))
    link = tmp_path / "in-the-volume" / "observer.sock"
    link.parent.mkdir()
    os.symlink(elsewhere, link)
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock, pytest.raises(ConnectionRefusedError,
                                                                                  match="not a socket"):
        connect_long(sock, link)
    metrics = AgentMetrics()
    assert SidecarObserver(lambda: link, metrics).servos() is None
    assert failures(metrics, "unreachable") == 1


def test_a_peer_trickling_its_reply_is_given_up_on_at_the_requests_deadline(peer) -> None:
    def trickle(conn: socket.socket) -> None:
        conn.recv(1024)
        try:
            for _ in range(100):
                conn.sendall(b" ")
                time.sleep(0.1)
        except OSError:
            return

    metrics = AgentMetrics()
    observer = SidecarObserver(lambda: peer(trickle), metrics, timeout_s=0.5)
    started = time.monotonic()
    assert observer.servos() is None
    assert time.monotonic() - started < 3  # one deadline for the reply, not one per byte
    assert failures(metrics, "failed") == 1


def test_a_reply_nested_too_deep_for_the_json_parser_is_a_failed_request(peer) -> None:
    def nested(conn: socket.socket) -> None:
        conn.recv(1024)
        conn.sendall(b"[" * 200_000 + b"]" * 200_000 + b"\n")

    metrics = AgentMetrics()
    assert SidecarObserver(lambda: peer(nested), metrics).rollout_events() == []
    assert failures(metrics, "failed") == 1


def test_the_jobs_end_takes_its_events_while_a_poll_waits_on_a_stalled_peer(peer) -> None:
    answered = threading.Event()

    def stall(conn: socket.socket) -> None:
        conn.recv(1024)
        answered.wait(5)

    observer = SidecarObserver(lambda: peer(stall), AgentMetrics(), timeout_s=3)
    poll = threading.Thread(target=observer.rollout_events, daemon=True)
    poll.start()
    time.sleep(0.3)  # the poll is now waiting for the stalled reply
    started = time.monotonic()
    assert observer.take_events([]) == []
    assert time.monotonic() - started < 1
    answered.set()
    poll.join(5)

"""Caps on what a hostile job can make the connector hold: connections, threads,
buffered bytes, error text, rollout fields; and an accept loop nothing can end."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import pytest
from armnet_connector.errors import MAX_ERROR_CHARS, failure_reply
from armnet_connector.server import (
    MAX_BUFFERED_BYTES,
    MAX_LINE_BYTES,
    FramingError,
    LineReader,
)

pytestmark = pytest.mark.unit


def connect(path: Path) -> socket.socket:
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    sock.settimeout(10)
    sock.connect(str(path))
    return sock


def exchange(sock: socket.socket, request: dict) -> dict:
    sock.sendall(json.dumps(request).encode() + b"\n")
    return read_reply(sock)


def read_reply(sock: socket.socket) -> dict:
    buffer = b""
    while not buffer.endswith(b"\n"):
        chunk = sock.recv(65536)
        if not chunk:
            break
        buffer += chunk
    return json.loads(buffer) if buffer else {}


def test_connections_over_the_cap_get_one_clear_error_and_the_socket_keeps_serving(
    make_connector, cell_config
) -> None:
    connector = make_connector(cell_config(None, maxConnections=3))
    path = connector.socket_dir / "robot.sock"
    held = [connect(path) for _ in range(3)]
    assert all(exchange(sock, {"op": "hello"})["ok"] for sock in held)
    with connect(path) as extra:
        refusal = read_reply(extra)
        assert extra.recv(1) == b""  # and the connection is closed
    assert refusal["error_type"] == "TooManyConnections" and "3 connections" in refusal["error"]
    assert connector.counters.connections_refused == 1
    held.pop().close()
    assert _served_again(path), "a freed slot was never served again"
    for sock in held:
        sock.close()
    assert _served_again(path), "the socket stopped serving after the crowd left"


def _served_again(path: Path, within_s: float = 10.0) -> bool:
    """Whether a new connection gets a hello answered: a freed slot is reusable once its thread saw the close."""
    deadline = time.monotonic() + within_s
    while True:
        try:
            with connect(path) as again:
                if exchange(again, {"op": "hello"}).get("ok"):
                    return True
        except OSError:  # refused while the slots were still taken: the server closed on its refusal
            pass
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)


def test_the_line_cap_is_sized_for_control_traffic() -> None:
    assert MAX_LINE_BYTES == 1 << 20 and MAX_BUFFERED_BYTES >= 16 * MAX_LINE_BYTES


def test_unfinished_lines_over_the_total_cap_close_the_connection_that_went_over(make_connector, cell_config) -> None:
    connector = make_connector(cell_config(None))
    budget = connector.request_budget
    path = connector.socket_dir / "operator.sock"
    almost_a_line = b"x" * (MAX_LINE_BYTES - 1)
    socks = []
    closed_by_budget = 0
    for _ in range(budget.limit // MAX_LINE_BYTES + 4):
        sock = connect(path)
        socks.append(sock)
        try:
            sock.sendall(almost_a_line)
        except (BrokenPipeError, ConnectionResetError):
            closed_by_budget += 1
    time.sleep(0.5)  # let the connection threads read what was sent
    replies = []
    for sock in socks:
        sock.settimeout(0.2)
        try:
            replies.append(sock.recv(4096))
        except TimeoutError:
            replies.append(b"")
    refused = [r for r in replies if b"too many unfinished request lines" in r]
    assert refused or closed_by_budget, "no connection was closed at the total cap"
    assert budget.used <= budget.limit
    for sock in socks:
        sock.close()
    with connect(path) as fresh:
        assert exchange(fresh, {"op": "should_stop"}) == {"ok": True, "stop": False}
    deadline = time.monotonic() + 5
    while budget.used and time.monotonic() < deadline:
        time.sleep(0.05)
    assert budget.used == 0  # every closed connection gave its bytes back


def test_a_line_spread_over_many_chunks_is_framed_once_and_intact() -> None:
    left, right = socket.socketpair()
    with left, right:
        reader = LineReader(right, limit=4 * 65536)
        payload = b"a" * (3 * 65536)

        def send() -> None:  # a writer of its own: the line is larger than the socket's buffer
            for start in range(0, len(payload), 4096):
                left.sendall(payload[start : start + 4096])
            left.sendall(b"\nsecond\nthird")
            left.shutdown(socket.SHUT_WR)

        writer = threading.Thread(target=send)
        writer.start()
        assert reader.next() == payload + b"\n"
        assert reader.next() == b"second\n"
        assert reader.next() == b"third"  # the peer closed mid-line
        writer.join(timeout=10)


def test_a_line_over_the_cap_is_a_framing_error() -> None:
    left, right = socket.socketpair()
    with left, right:
        reader = LineReader(right, limit=1000)
        left.sendall(b"y" * 70000)
        with pytest.raises(FramingError, match="longer than 1000 bytes"):
            reader.next()


def test_error_text_sent_to_a_client_is_bounded(make_connector, cell_config, client_for, motors) -> None:
    assert len(failure_reply(ValueError("v" * 10**6))["error"]) < MAX_ERROR_CHARS + 100
    connector = make_connector(cell_config(None))
    client = client_for(connector.robot_endpoint)
    reply = client.request({"op": "call", "object_id": "o" * 500_000, "method": "read", "args": [], "kwargs": {}})
    assert reply["ok"] is False and len(reply["error"]) < MAX_ERROR_CHARS + 100


def test_rollout_fields_are_bounded_and_the_history_keeps_the_latest(make_connector, cell_config, client_for) -> None:
    connector = make_connector(cell_config(None))
    client = client_for(connector.operator_endpoint)
    reply = client.request({"op": "rollout_begin", "index": 10**15})
    assert reply["error_type"] == "ProtocolError" and "rollout index" in reply["error"]
    for index in range(1500):
        assert client.request({"op": "rollout_begin", "index": index, "total": 1500})["ok"]
    assert len(connector.cell.rollouts) == 1024 and connector.cell.rollouts[-1].index == 1499


def _connector_process(
    config_path: Path, socket_dir: Path, preamble: str = "", *, stdin: int | None = None
) -> subprocess.Popen[str]:
    """``armnet connector`` in a child process, after an optional Python ``preamble``."""
    script = textwrap.dedent(preamble) + textwrap.dedent(
        """
        import sys
        from armnet_cli.main import main
        sys.exit(main(["connector", "--config", sys.argv[1], "--socket-dir", sys.argv[2]]))
        """
    )
    return subprocess.Popen(
        [sys.executable, "-c", script, str(config_path), str(socket_dir)],
        stderr=subprocess.PIPE, stdin=stdin, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )


def _wait_serving(process: subprocess.Popen[str]) -> None:
    assert process.stderr is not None
    for _ in range(50):
        line = process.stderr.readline()
        if "serving" in line or not line:
            assert "serving" in line, "the connector did not start"
            return
    raise AssertionError("the connector did not say it was serving")


def test_at_the_descriptor_limit_the_accept_loop_backs_off_logs_little_and_recovers(
    cell_config, socket_dir: Path, tmp_path: Path
) -> None:
    config = tmp_path / "cell.json"
    config.write_text(cell_config(None).model_dump_json(by_alias=True))
    preamble = """
        import resource
        resource.setrlimit(resource.RLIMIT_NOFILE, (48, 48))
    """
    process = _connector_process(config, socket_dir, preamble)
    try:
        _wait_serving(process)
        path = socket_dir / "robot.sock"
        crowd = [connect(path) for _ in range(60)]  # more than the connector has descriptors for
        time.sleep(2.0)  # the accept loop meets EMFILE again and again meanwhile
        for sock in crowd:
            sock.close()
        deadline = time.monotonic() + 10
        while True:
            try:
                with connect(path) as sock:
                    if exchange(sock, {"op": "hello"}).get("ok"):
                        break
            except OSError:
                pass
            assert time.monotonic() < deadline, "the connector stopped accepting after the descriptor limit"
            time.sleep(0.1)
        process.send_signal(signal.SIGTERM)
        _, stderr = process.communicate(timeout=20)
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()
    assert "accept on robot.sock failed" in stderr
    assert len(stderr) < 20_000, f"{len(stderr)} bytes of log in 2 s"


def test_a_connection_no_thread_can_be_started_for_is_refused_and_the_next_one_served(
    cell_config, socket_dir: Path, tmp_path: Path
) -> None:
    """Starting the connection's thread fails as at the host's thread limit (the child's
    ``Thread.start`` raises what CPython raises then, for connection threads only, until a
    line on stdin lifts it): resource limits could not be made to bite reliably in a
    process whose threads were started before the limit."""
    config = tmp_path / "cell.json"
    config.write_text(cell_config(None).model_dump_json(by_alias=True))
    preamble = """
        import sys, threading

        _real_start = threading.Thread.start
        starved = threading.Event()
        starved.set()

        def _start(self):
            if starved.is_set() and self.name.startswith("armnet-conn-"):
                raise RuntimeError("can't start new thread")
            return _real_start(self)

        def lift():
            sys.stdin.readline()
            starved.clear()

        threading.Thread(target=lift, daemon=True).start()
        threading.Thread.start = _start
    """
    process = _connector_process(config, socket_dir, preamble, stdin=subprocess.PIPE)
    try:
        _wait_serving(process)
        path = socket_dir / "robot.sock"
        with connect(path) as sock:
            refusal = read_reply(sock)
        assert refusal["error_type"] == "TooManyConnections" and "cannot start a thread" in refusal["error"], refusal
        assert process.stdin is not None
        process.stdin.write("lift\n")
        process.stdin.flush()
        deadline = time.monotonic() + 10
        while True:
            # Until the child's lift thread has run, a connection is still refused: the
            # connector sends its refusal and closes, which our send may meet as a broken pipe.
            with connect(path) as sock:
                try:
                    served = exchange(sock, {"op": "hello"}).get("ok")
                except (BrokenPipeError, ConnectionResetError):
                    served = False
                if served:
                    break
            assert time.monotonic() < deadline, "the accept loop did not survive a failed thread start"
            time.sleep(0.1)
    finally:
        process.send_signal(signal.SIGTERM)
        try:
            process.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            process.kill()
            process.communicate()


def test_sigterm_ends_the_connector_within_the_grace_window_under_load(
    sim_cell, cell_config, socket_dir: Path, tmp_path: Path, motors, calibration
) -> None:
    """Busy connections keep every thread but the main one running; SIGTERM still
    ends the process within the grace window, the arm at rest and its torque off."""

    from armnet_runtime.lerobot.remote_feetech import RemoteFeetechMotorsBus

    # The window the connector must end in; generous because a CI host building images beside the
    # suite left this process's main thread (the one SIGTERM runs on) waiting 8 s for a core.
    grace_s = 15.0
    rest = {"elbow_flex": 1800, "wrist_roll": 2600}
    cell = cell_config(sim_cell, gracePeriodSeconds=grace_s, restOnShutdown=True)
    cell = cell.model_copy(update={"arms": {"arm": cell.arms["arm"].model_copy(update={"rest_pose": rest})}})
    config = tmp_path / "cell.json"
    config.write_text(cell.model_dump_json(by_alias=True))
    process = _connector_process(config, socket_dir)
    stop_load = threading.Event()
    endpoint = f"unix://{socket_dir}/robot.sock"

    def hammer() -> None:
        try:
            bus = RemoteFeetechMotorsBus(port=endpoint, motors=motors, calibration=calibration)
            bus.connect()
            while not stop_load.is_set():
                bus.sync_read("Present_Position")
        except Exception:  # noqa: BLE001 — the connector going away ends the load
            return

    def chatter() -> None:
        try:
            with connect(socket_dir / "operator.sock") as sock:
                while not stop_load.is_set():
                    exchange(sock, {"op": "should_stop"})
        except (OSError, ValueError):
            return

    threads = [threading.Thread(target=hammer) for _ in range(3)] + [threading.Thread(target=chatter) for _ in range(8)]
    try:
        _wait_serving(process)
        holder = RemoteFeetechMotorsBus(port=endpoint, motors=motors, calibration=calibration)
        holder.connect()
        holder.enable_torque()
        for thread in threads:
            thread.start()
        time.sleep(1.0)
        assert all(sim_cell.arm.torque_enabled().values())
        before = sim_cell.arm.positions()
        assert any(abs(before[m] - goal) > 100 for m, goal in rest.items()), "the arm starts at rest"
        sent = time.monotonic()
        process.send_signal(signal.SIGTERM)
        _, log_text = process.communicate(timeout=grace_s + 5)
        took = time.monotonic() - sent
    finally:
        stop_load.set()
        if process.poll() is None:
            process.kill()
            process.communicate()
        for thread in threads:
            thread.join(timeout=10)
    assert process.returncode == 0
    assert took < grace_s, f"SIGTERM took {took:.1f} s, over the {grace_s:g} s grace window:\n{log_text[-3000:]}"
    assert not any(sim_cell.arm.torque_enabled().values())
    positions = sim_cell.arm.positions()
    assert all(abs(positions[m] - goal) <= 25 for m, goal in rest.items()), positions

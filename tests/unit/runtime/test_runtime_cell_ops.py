"""Cell operations against a real JSON-lines peer on a unix socket (runtime/PROTOCOL.md)."""

from __future__ import annotations

import collections
import logging
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from typing import Any

import pytest
from armnet_runtime.context import Cell, CompletionStatus, ResetTimeoutException
from armnet_runtime.errors import ConnectorUnavailable, ProtocolError

from tests.support.jsonl_server import HANG_UP, WEDGE, JsonlServer

pytestmark = [pytest.mark.unit, pytest.mark.timeout(30)]


class OperatorPeer:
    """The operator-socket state a connector keeps: latest teleop action, FIFO events, outcomes."""

    def __init__(self) -> None:
        self.action: dict[str, float] | None = None
        self.events: collections.deque[str] = collections.deque()
        self.outcome: bool | None = None
        self.shutting_down = False
        self.stop = False
        self.reset_reply: dict[str, Any] = {"ok": True}
        self.reset_delay_s = 0.0
        self.overrides: dict[str, Any] = {}

    def __call__(self, request: dict[str, Any]) -> Any:
        op = request["op"]
        if op in self.overrides:
            return self.overrides[op]
        if op == "get_teleop":
            return {"ok": True, "action": self.action}
        if op == "get_teleop_event":
            return {"ok": True, "event": self.events.popleft() if self.events else None}
        if op == "get_completion":
            outcome, self.outcome = self.outcome, None
            return {"ok": True, "reported": outcome is not None, "success": bool(outcome)}
        if op == "shutdown_status":
            return {"ok": True, "shutting_down": self.shutting_down, "grace_remaining_s": None}
        if op == "should_stop":
            return {"ok": True, "stop": self.stop}
        if op == "reset":
            time.sleep(self.reset_delay_s)
            return self.reset_reply
        if op in ("rollout_begin", "rollout_end"):
            return {"ok": True}
        return {"ok": False, "error": f"unknown op {op}", "error_type": "UnknownOp"}


class RobotPeer:
    def __init__(self) -> None:
        self.complete = False
        self.overrides: dict[str, Any] = {}

    def __call__(self, request: dict[str, Any]) -> Any:
        op = request["op"]
        if op in self.overrides:
            return self.overrides[op]
        if op == "return_to_rest":
            return {"ok": True}
        if op == "is_complete":
            return {"ok": True, "complete": self.complete, "success": self.complete}
        return {"ok": False, "error": f"unknown op {op}", "error_type": "UnknownOp"}


@pytest.fixture
def sock_dir() -> Iterator[str]:
    path = tempfile.mkdtemp(prefix="armnet-ops-", dir="/tmp")  # short: unix paths max 107 bytes
    yield path
    shutil.rmtree(path, ignore_errors=True)


@pytest.fixture
def operator(sock_dir: str) -> Iterator[tuple[OperatorPeer, JsonlServer]]:
    peer = OperatorPeer()
    with JsonlServer(os.path.join(sock_dir, "operator.sock"), peer) as server:
        yield peer, server


@pytest.fixture
def robot(sock_dir: str) -> Iterator[tuple[RobotPeer, JsonlServer]]:
    peer = RobotPeer()
    with JsonlServer(os.path.join(sock_dir, "robot.sock"), peer) as server:
        yield peer, server


# --- no endpoint attached -------------------------------------------------------------------


def test_without_endpoints_the_polled_ops_return_the_neutral_answer() -> None:
    cell = Cell()
    assert cell.get_teleop_action() is None
    assert cell.get_teleop_event() is None
    assert cell.is_shutting_down() is False
    assert cell.should_stop() is False
    assert cell.is_complete() == CompletionStatus(complete=False, success=False)
    cell.rollout_begin(index=1, total=2)
    cell.rollout_end()


def test_reset_without_endpoint_prompts_on_the_terminal() -> None:
    code = "from armnet_runtime.context import Cell\nCell().reset()\nprint('after reset')\n"
    out = subprocess.run(
        [sys.executable, "-c", code], input="\n", capture_output=True, text=True, timeout=20,
        check=True,
    )
    assert out.stdout == (
        "[armnet:progress] Waiting for workspace reset...\n"
        "Reset the cell workspace, then press Enter. after reset\n"
    )


def test_reset_without_endpoint_blocks_until_enter() -> None:
    code = "from armnet_runtime.context import Cell\nCell().reset()\nprint('after reset')\n"
    proc = subprocess.Popen(
        [sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        assert proc.stdout is not None and proc.stdin is not None
        assert proc.stdout.readline() == "[armnet:progress] Waiting for workspace reset...\n"
        assert proc.poll() is None  # still waiting for the operator
        proc.stdin.write("\n")
        proc.stdin.close()
        assert proc.stdout.read().endswith("after reset\n")
        assert proc.wait(timeout=20) == 0
    finally:
        proc.kill()
        proc.wait()


# --- teleop ---------------------------------------------------------------------------------


def test_teleop_action_is_the_latest_value_and_none_before_any(
    operator: tuple[OperatorPeer, JsonlServer],
) -> None:
    peer, server = operator
    cell = Cell(operator_call_endpoint=server.endpoint)
    assert cell.get_teleop_action() is None
    peer.action = {"shoulder_pan.pos": 1.0}
    peer.action = {"shoulder_pan.pos": 12.5, "gripper.pos": 3}
    assert cell.get_teleop_action() == {"shoulder_pan.pos": 12.5, "gripper.pos": 3.0}
    assert cell.get_teleop_action() == {"shoulder_pan.pos": 12.5, "gripper.pos": 3.0}


def test_teleop_events_are_popped_fifo_one_per_call(
    operator: tuple[OperatorPeer, JsonlServer],
) -> None:
    peer, server = operator
    peer.events.extend(["next_episode", "rerecord_episode", "stop_recording"])
    cell = Cell(operator_call_endpoint=server.endpoint)
    got = [cell.get_teleop_event() for _ in range(4)]
    assert got == ["next_episode", "rerecord_episode", "stop_recording", None]


def test_polled_ops_reuse_one_connection(operator: tuple[OperatorPeer, JsonlServer]) -> None:
    _, server = operator
    cell = Cell(operator_call_endpoint=server.endpoint)
    for _ in range(5):
        cell.get_teleop_action()
        cell.get_teleop_event()
    assert server.connections == 1
    assert server.ops() == ["get_teleop", "get_teleop_event"] * 5


def test_local_control_endpoint_is_the_fallback_for_operator_ops(
    operator: tuple[OperatorPeer, JsonlServer],
) -> None:
    peer, server = operator
    peer.action = {"a": 1}
    assert Cell(local_control_endpoint=server.endpoint).get_teleop_action() == {"a": 1.0}


def test_teleop_reconnects_after_the_server_restarts(
    operator: tuple[OperatorPeer, JsonlServer],
) -> None:
    peer, server = operator
    peer.action = {"a": 1.0}
    cell = Cell(operator_call_endpoint=server.endpoint)
    assert cell.get_teleop_action() == {"a": 1.0}
    server.stop()
    assert cell.get_teleop_action() is None  # connector gone: hold position
    assert cell.get_teleop_action() is None  # still gone: no exception either
    server.start()
    peer.action = {"a": 2.0}
    assert cell.get_teleop_action() == {"a": 2.0}
    assert cell.get_teleop_event() is None


@pytest.mark.timeout(10)
def test_a_wedged_peer_costs_one_bounded_read_then_the_next_call_reconnects(
    operator: tuple[OperatorPeer, JsonlServer],
) -> None:
    peer, server = operator
    peer.action = {"a": 1.0}
    peer.overrides["get_teleop"] = WEDGE
    cell = Cell(operator_call_endpoint=server.endpoint)
    assert cell.get_teleop_action() is None
    del peer.overrides["get_teleop"]
    assert cell.get_teleop_action() == {"a": 1.0}
    assert server.connections == 2


@pytest.mark.timeout(10)
def test_a_wedged_peer_never_stalls_the_other_polled_ops(
    operator: tuple[OperatorPeer, JsonlServer],
) -> None:
    peer, server = operator
    for op in ("get_teleop_event", "get_completion", "shutdown_status", "should_stop"):
        peer.overrides[op] = WEDGE
    cell = Cell(operator_call_endpoint=server.endpoint)
    assert cell.get_teleop_event() is None
    assert cell._human_completion() is None
    assert cell.is_shutting_down() is False
    assert cell.should_stop() is False


def test_garbage_replies_read_as_no_teleop_with_a_warning(
    operator: tuple[OperatorPeer, JsonlServer], caplog: pytest.LogCaptureFixture
) -> None:
    peer, server = operator
    peer.overrides["get_teleop"] = b"<html>not the connector</html>\n"
    peer.overrides["get_teleop_event"] = b'["ok"]\n'
    cell = Cell(operator_call_endpoint=server.endpoint)
    with caplog.at_level(logging.WARNING, logger="armnet_runtime.context"):
        assert cell.get_teleop_action() is None
    assert "not JSON" in caplog.text and "<html>" in caplog.text
    cell._teleop_last_error_log = 0.0  # let the next warning through the throttle
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="armnet_runtime.context"):
        assert cell.get_teleop_event() is None
    assert "ProtocolError" in caplog.text and "boolean" in caplog.text


def test_repeated_failures_log_one_throttled_warning(
    sock_dir: str, caplog: pytest.LogCaptureFixture
) -> None:
    cell = Cell(operator_call_endpoint=f"unix://{sock_dir}/nobody-listens.sock")
    with caplog.at_level(logging.WARNING, logger="armnet_runtime.context"):
        for _ in range(10):
            assert cell.get_teleop_action() is None
    assert len([r for r in caplog.records if "teleop read" in r.getMessage()]) == 1


def test_error_replies_read_as_no_teleop(operator: tuple[OperatorPeer, JsonlServer]) -> None:
    peer, server = operator
    peer.overrides["get_teleop"] = {"ok": False, "error": "no teleop client", "error_type": "X"}
    peer.overrides["get_teleop_event"] = HANG_UP
    cell = Cell(operator_call_endpoint=server.endpoint)
    assert cell.get_teleop_action() is None
    assert cell.get_teleop_event() is None


# --- rollout, completion, shutdown, stop -------------------------------------------------


def test_rollout_begin_sends_index_total_and_outcome_controls(
    operator: tuple[OperatorPeer, JsonlServer],
) -> None:
    _, server = operator
    cell = Cell(operator_call_endpoint=server.endpoint)
    cell.rollout_begin(index=3, total=10)
    cell.rollout_begin(outcome_controls=False)
    cell.rollout_end()
    assert server.requests == [
        {"op": "rollout_begin", "outcome_controls": True, "index": 3, "total": 10},
        {"op": "rollout_begin", "outcome_controls": False},
        {"op": "rollout_end"},
    ]


def test_rollout_signals_are_best_effort(sock_dir: str) -> None:
    cell = Cell(operator_call_endpoint=f"unix://{sock_dir}/gone.sock")
    cell.rollout_begin(index=1)
    cell.rollout_end()


def test_a_human_outcome_wins_and_is_consumed(
    operator: tuple[OperatorPeer, JsonlServer], robot: tuple[RobotPeer, JsonlServer]
) -> None:
    op_peer, op_server = operator
    robot_peer, robot_server = robot
    robot_peer.complete = True
    op_peer.outcome = False  # the operator ended the rollout as a failure
    cell = Cell(operator_call_endpoint=op_server.endpoint, robot_port=robot_server.endpoint)
    status = cell.is_complete()
    assert status == CompletionStatus(complete=True, success=False) and bool(status)
    assert robot_server.requests == []
    assert cell.is_complete() == CompletionStatus(complete=True, success=True)  # the monitor
    assert robot_server.requests == [{"op": "is_complete", "block": False}]


def test_is_complete_asks_the_monitor_with_block(
    operator: tuple[OperatorPeer, JsonlServer], robot: tuple[RobotPeer, JsonlServer]
) -> None:
    _, op_server = operator
    _, robot_server = robot
    cell = Cell(operator_call_endpoint=op_server.endpoint, robot_port=robot_server.endpoint)
    status = cell.is_complete(block=True)
    assert status == CompletionStatus(False, False) and not status
    assert robot_server.requests == [{"op": "is_complete", "block": True}]


def test_is_complete_reports_a_garbage_robot_reply_clearly(
    robot: tuple[RobotPeer, JsonlServer],
) -> None:
    peer, server = robot
    peer.overrides["is_complete"] = b"\x00\xffgarbage\n"
    with pytest.raises(ProtocolError, match="not JSON"):
        Cell(robot_port=server.endpoint).is_complete()


def test_is_complete_ignores_a_device_path_robot_port() -> None:
    assert Cell(robot_port="/dev/ttyACM0").is_complete() == CompletionStatus(False, False)


def test_is_shutting_down_follows_the_grace_window(
    operator: tuple[OperatorPeer, JsonlServer],
) -> None:
    peer, server = operator
    cell = Cell(operator_call_endpoint=server.endpoint)
    assert cell.is_shutting_down() is False
    peer.shutting_down = True
    assert cell.is_shutting_down() is True
    server.stop()
    assert cell.is_shutting_down() is False


def test_should_stop_polls_the_operator_endpoint(operator: tuple[OperatorPeer, JsonlServer]) -> None:
    peer, server = operator
    cell = Cell(operator_call_endpoint=server.endpoint)
    assert cell.should_stop() is False
    peer.stop = True
    assert cell.should_stop() is True


def test_should_stop_on_the_local_control_endpoint_raises_its_errors(
    operator: tuple[OperatorPeer, JsonlServer],
) -> None:
    peer, server = operator
    peer.overrides["should_stop"] = {"ok": False, "error": "control panel offline"}
    with pytest.raises(RuntimeError, match="control panel offline"):
        Cell(local_control_endpoint=server.endpoint).should_stop()


# --- reset ----------------------------------------------------------------------------------


def test_reset_returns_to_rest_then_waits_for_the_operator(
    operator: tuple[OperatorPeer, JsonlServer],
    robot: tuple[RobotPeer, JsonlServer],
    capsys: pytest.CaptureFixture[str],
) -> None:
    op_peer, op_server = operator
    _, robot_server = robot
    op_peer.reset_delay_s = 1.0  # longer than any polled read bound: reset has no client timeout
    cell = Cell(operator_call_endpoint=op_server.endpoint, robot_port=robot_server.endpoint)
    cell.reset()
    assert robot_server.requests == [{"op": "return_to_rest"}]
    assert op_server.requests == [{"op": "reset", "request": {"kind": "manual"}}]
    assert capsys.readouterr().out == "[armnet:progress] Waiting for workspace reset...\n"


def test_reset_timeout_raises_reset_timeout_exception(
    operator: tuple[OperatorPeer, JsonlServer],
) -> None:
    peer, server = operator
    peer.reset_reply = {
        "ok": False, "error": "no operator confirmed the reset within 300 s",
        "error_type": "ResetTimeoutException",
    }
    with pytest.raises(ResetTimeoutException, match="within 300 s"):
        Cell(operator_call_endpoint=server.endpoint).reset()


def test_other_reset_failures_raise_runtime_error(
    operator: tuple[OperatorPeer, JsonlServer], robot: tuple[RobotPeer, JsonlServer]
) -> None:
    op_peer, op_server = operator
    robot_peer, robot_server = robot
    op_peer.reset_reply = {"ok": False, "error": "interlock tripped", "error_type": "InterlockTripped"}
    with pytest.raises(RuntimeError, match="interlock tripped") as info:
        Cell(operator_call_endpoint=op_server.endpoint).reset()
    assert not isinstance(info.value, ResetTimeoutException)
    robot_peer.overrides["return_to_rest"] = {"ok": False, "error": "bus unplugged"}
    with pytest.raises(RuntimeError, match="bus unplugged"):
        Cell(robot_port=robot_server.endpoint, operator_call_endpoint=op_server.endpoint).reset()
    assert op_server.ops() == ["reset"]  # no confirmation asked after a failed rest move


def test_reset_with_an_unreachable_operator_endpoint_raises_connection_error(sock_dir: str) -> None:
    with pytest.raises(ConnectorUnavailable, match="cannot reach"):
        Cell(operator_call_endpoint=f"unix://{sock_dir}/gone.sock").reset()


def test_polling_from_two_threads_is_safe(operator: tuple[OperatorPeer, JsonlServer]) -> None:
    peer, server = operator
    peer.action = {"a": 1.0}
    cell = Cell(operator_call_endpoint=server.endpoint)
    results: list[Any] = []

    def poll() -> None:
        for _ in range(50):
            results.append(cell.get_teleop_action())

    threads = [threading.Thread(target=poll) for _ in range(2)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert results == [{"a": 1.0}] * 100

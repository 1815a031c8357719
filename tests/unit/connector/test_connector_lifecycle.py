"""Deadline and grace window, operator inputs, and the `armnet connector` process lifecycle."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from armnet_connector.inputs import LocalOperatorInputs, apply_input_line, feed_lines

pytestmark = pytest.mark.unit


def test_the_deadline_trips_the_interlock_and_opens_the_grace_window(make_connector, cell_config, client_for) -> None:
    expired = threading.Event()
    # Seconds, not tenths: a loaded host may stall the test for a few hundred milliseconds.
    connector = make_connector(
        cell_config(None, timeoutSeconds=1.0, gracePeriodSeconds=2.0), on_grace_expired=expired.set
    )
    operator = client_for(connector.operator_endpoint)
    assert operator.request({"op": "shutdown_status"}) == {"ok": True, "shutting_down": False, "grace_remaining_s": None}
    deadline = time.monotonic() + 10
    while not (status := operator.request({"op": "shutdown_status"}))["shutting_down"]:
        assert time.monotonic() < deadline, "the deadline never passed"
        time.sleep(0.05)
    assert 0 < status["grace_remaining_s"] <= 2.0
    assert connector.deadline_passed and connector.interlock.tripped
    assert not expired.is_set()
    assert expired.wait(10)
    assert connector.grace_expired


def test_past_the_deadline_motion_is_refused_as_shutting_down(make_connector, cell_config, client_for) -> None:
    connector = make_connector(cell_config(None))
    connector.pass_deadline()
    reply = client_for(connector.robot_endpoint).request({"op": "return_to_rest"})
    assert reply["error_type"] == "ShuttingDown" and "is_shutting_down" in reply["error"]


def test_a_deadline_the_hosts_clock_passed_names_the_jobs_timeout_as_configured(make_connector, cell_config) -> None:
    connector = make_connector(cell_config(None))  # no timeout of its own: armnet run's and the agent's clock
    connector.pass_deadline(2)
    trip = connector.interlock.trip_info
    assert trip is not None and trip.message == "the job exceeded its timeout of 2 s"


def test_the_connectors_own_deadline_names_its_timeout_without_a_float_tail(make_connector, cell_config) -> None:
    connector = make_connector(cell_config(None, timeoutSeconds=600))
    connector.pass_deadline()
    trip = connector.interlock.trip_info
    assert trip is not None and trip.message == "the job exceeded its timeout of 600 s"


def test_a_cancel_trips_the_interlock_naming_the_cancel_not_a_timeout(make_connector, cell_config) -> None:
    connector = make_connector(cell_config(None))
    connector.cancel()
    trip = connector.interlock.trip_info
    assert trip is not None and trip.message == "the job was cancelled"
    assert connector.deadline_passed and connector.cell.deadline.grace_remaining_s() is not None


def test_a_cancelled_job_is_refused_motion_with_the_cancel_named(make_connector, cell_config, client_for) -> None:
    connector = make_connector(cell_config(None, timeoutSeconds=600))
    connector.cancel()
    reply = client_for(connector.robot_endpoint).request({"op": "return_to_rest"})
    assert reply["error_type"] == "ShuttingDown"
    assert "cancelled" in reply["error"] and "timeout" not in reply["error"]


def test_without_a_timeout_there_is_no_deadline(make_connector, cell_config) -> None:
    connector = make_connector(cell_config(None))
    time.sleep(0.1)
    assert not connector.deadline_passed and not connector.interlock.tripped


def test_teleop_actions_latest_wins_and_events_are_fifo(make_connector, cell_config, client_for) -> None:
    inputs = LocalOperatorInputs()
    connector = make_connector(cell_config(None), inputs=inputs)
    operator = client_for(connector.operator_endpoint)
    assert operator.request({"op": "get_teleop"}) == {"ok": True, "action": None}
    inputs.set_teleop_action({"elbow_flex.pos": 1.0})
    inputs.set_teleop_action({"elbow_flex.pos": 2.0})
    inputs.push_teleop_event("next_episode")
    inputs.push_teleop_event("stop_recording")
    assert operator.request({"op": "get_teleop"})["action"] == {"elbow_flex.pos": 2.0}
    assert operator.request({"op": "get_teleop"})["action"] == {"elbow_flex.pos": 2.0}
    events = [operator.request({"op": "get_teleop_event"})["event"] for _ in range(3)]
    assert events == ["next_episode", "stop_recording", None]


def test_a_reported_outcome_is_consumed_when_read(make_connector, cell_config, client_for) -> None:
    inputs = LocalOperatorInputs()
    connector = make_connector(cell_config(None), inputs=inputs)
    operator = client_for(connector.operator_endpoint)
    inputs.report_outcome(False)
    assert operator.request({"op": "get_completion"}) == {"ok": True, "reported": True, "success": False}
    assert operator.request({"op": "get_completion"}) == {"ok": True, "reported": False, "success": False}


def test_is_complete_defaults_to_never(make_connector, cell_config, client_for) -> None:
    connector = make_connector(cell_config(None))
    reply = client_for(connector.robot_endpoint).request({"op": "is_complete", "block": True})
    assert reply == {"ok": True, "complete": False, "success": False}


def test_stop_requests_and_rollouts_are_recorded(make_connector, cell_config, client_for) -> None:
    inputs = LocalOperatorInputs()
    connector = make_connector(cell_config(None), inputs=inputs)
    operator = client_for(connector.operator_endpoint)
    assert operator.request({"op": "should_stop"})["stop"] is False
    inputs.request_stop()
    assert operator.request({"op": "should_stop"})["stop"] is True
    assert operator.request({"op": "rollout_begin", "index": 1, "total": 3, "outcome_controls": True}) == {"ok": True}
    assert operator.request({"op": "rollout_end"}) == {"ok": True}
    assert [(e.kind, e.index, e.total) for e in connector.cell.rollouts] == [("begin", 1, 3), ("end", None, None)]
    assert operator.request({"op": "rollout_begin", "index": "one"})["error_type"] == "ProtocolError"


def test_input_lines_feed_every_kind_of_input() -> None:
    inputs = LocalOperatorInputs()
    feed_lines(
        inputs,
        [
            '{"teleop_action": {"gripper.pos": 5}}\n', '{"teleop_event": "rerecord_episode"}\n',
            '{"outcome": true}\n', '{"stop": true}\n', "\n", "garbage\n",
        ],
    )
    assert inputs.latest_teleop_action() == {"gripper.pos": 5}
    assert inputs.next_teleop_event() == "rerecord_episode"
    assert inputs.take_outcome() is True and inputs.stop_requested()


def test_an_unknown_input_line_says_what_is_accepted() -> None:
    with pytest.raises(ValueError, match="accepted keys"):
        apply_input_line(LocalOperatorInputs(), '{"launch": "missiles"}')


def test_auto_confirm_confirms_every_reset() -> None:
    assert LocalOperatorInputs(auto_confirm_reset=True).wait_reset_confirmation(0) is True


def test_the_command_serves_until_sigterm_then_releases_torque_and_removes_sockets(
    sim_cell, cell_config, socket_dir: Path, tmp_path: Path, motors, calibration
) -> None:
    from armnet_runtime.lerobot.remote_feetech import RemoteFeetechMotorsBus

    config = tmp_path / "cell.json"
    config.write_text(cell_config(sim_cell).model_dump_json(by_alias=True))
    inputs = tmp_path / "inputs.jsonl"
    inputs.write_text(json.dumps({"teleop_event": "next_episode"}) + "\n")
    process = subprocess.Popen(
        [sys.executable, "-m", "armnet_cli.main", "connector", "--config", str(config),
         "--socket-dir", str(socket_dir), "--inputs", str(inputs)],
        stderr=subprocess.PIPE, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    try:
        assert "serving" in (process.stderr.readline() if process.stderr else "")
        bus = RemoteFeetechMotorsBus(port=f"unix://{socket_dir}/robot.sock", motors=motors, calibration=calibration)
        bus.connect()
        bus.enable_torque()
        assert all(sim_cell.arm.torque_enabled().values())
        process.send_signal(signal.SIGTERM)
        assert process.wait(timeout=20) == 0
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    assert not any(sim_cell.arm.torque_enabled().values())
    assert not (socket_dir / "robot.sock").exists() and not (socket_dir / "operator.sock").exists()

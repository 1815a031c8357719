"""The agent's RobotJob status writes, from what happened in the run."""

from __future__ import annotations

import json
from datetime import UTC, datetime

import pytest
from armnet_core import JobResult, JobStatus
from armnet_node.report import (
    ERROR_MAX,
    TAIL_MAX,
    ConnectorRecord,
    end_detail,
    failed_before_start,
    running_patch,
    terminal_patch,
)

pytestmark = pytest.mark.unit

T0 = datetime(2026, 3, 1, 12, 0, 0, 250000, tzinfo=UTC)


def result(**overrides: object) -> JobResult:
    base: dict[str, object] = {"status": JobStatus.SUCCEEDED, "exit_code": 0, "started_at": T0, "finished_at": T0}
    base.update(overrides)
    return JobResult(**base)  # type: ignore[arg-type]


def test_every_phase_changing_write_carries_the_resource_version_it_was_decided_on() -> None:
    assert running_patch("41", T0)["metadata"]["resourceVersion"] == "41"
    assert terminal_patch("42", result())["metadata"]["resourceVersion"] == "42"
    assert failed_before_start("43", "boom", T0)["metadata"]["resourceVersion"] == "43"


def test_running_sets_started_at_in_milliseconds() -> None:
    assert running_patch("1", T0)["status"] == {"phase": "running", "startedAt": "2026-03-01T12:00:00.250Z"}


def test_a_success_reports_exit_code_and_return_value() -> None:
    body = terminal_patch("1", result(return_value={"ok": True}, stdout="hi"))["status"]
    assert body["phase"] == "succeeded"
    assert body["result"] == {"exitCode": 0, "returnValue": {"ok": True}, "stdoutTail": "hi", "stderrTail": ""}


def test_a_safety_violation_is_reported_from_the_connectors_record() -> None:
    record = ConnectorRecord(trip_reason="safety", trip_message="shoulder_pan: step 60 > limit 10 (present 3)")
    body = terminal_patch("1", result(status=JobStatus.FAILED, exit_code=1, traceback="SafetyViolation"), record)
    assert "shoulder_pan: step 60 > limit 10" in body["status"]["result"]["error"]


def test_a_deadline_trip_is_not_called_a_safety_violation() -> None:
    record = ConnectorRecord(trip_reason="deadline", trip_message="the job exceeded its timeout")
    body = terminal_patch("1", result(status=JobStatus.TIMEOUT, error="job exceeded"), record)
    assert "safety" not in body["status"]["result"]["error"]


def test_tails_and_errors_are_cut_to_the_crd_limits_keeping_the_end() -> None:
    body = terminal_patch("1", result(stdout="a" * 50_000 + "END", error="e" * 20_000 + "LAST"))["status"]["result"]
    assert len(body["stdoutTail"]) <= TAIL_MAX and body["stdoutTail"].endswith("END")
    assert len(body["error"]) <= ERROR_MAX and body["error"].endswith("LAST")


def test_the_last_rollout_goes_to_status() -> None:
    body = terminal_patch("1", result(), ConnectorRecord(rollout_index=3, rollout_total=5))
    assert body["status"]["rollout"] == {"index": 3, "total": 5}


def test_a_failure_before_start_has_an_error_and_no_traceback() -> None:
    body = failed_before_start("1", "Secret 'hf' does not exist in namespace team-a", T0)
    assert body["status"]["phase"] == "failed"
    assert body["status"]["result"] == {"error": "Secret 'hf' does not exist in namespace team-a"}
    assert "traceback" not in json.dumps(body)


def test_the_connectors_safety_report_lands_in_the_result() -> None:
    safety = {"policy": "clamp", "clampsPerMotor": {"shoulder_pan": 3}, "refusalsTotal": 0, "interlockTrips": 0}
    body = terminal_patch("7", result(), ConnectorRecord(safety=safety))
    assert body["status"]["result"]["safety"] == safety


def test_a_job_without_a_connector_record_carries_no_safety_field() -> None:
    assert "safety" not in terminal_patch("7", result())["status"]["result"]


def test_non_finite_numbers_a_job_chose_still_give_a_status_the_api_server_parses() -> None:
    safety = {"largestRequestedStep": {"shoulder_pan": float("inf"), "gripper": float("nan"), "elbow_flex": 2.5}}
    body = terminal_patch("7", result(), ConnectorRecord(safety=safety))
    text = json.dumps(body, allow_nan=False)  # raises on inf/nan, as the API server would refuse them
    steps = json.loads(text)["status"]["result"]["safety"]["largestRequestedStep"]
    assert steps == {"shoulder_pan": "inf", "gripper": "nan", "elbow_flex": 2.5}


def test_the_streams_end_message_carries_the_error_the_status_has() -> None:
    record = ConnectorRecord(trip_reason="safety", trip_message="shoulder_pan: step 60 > limit 10")
    failed = terminal_patch("1", result(status=JobStatus.FAILED, exit_code=1, error="exit code 1"), record)
    assert end_detail(failed) == {"exitCode": 1, "error": failed["status"]["result"]["error"]}
    assert "shoulder_pan: step 60" in end_detail(failed)["error"]
    assert end_detail(failed_before_start("1", "image x not found on this node", T0)) == {
        "error": "image x not found on this node"}
    assert end_detail(terminal_patch("1", result())) == {"exitCode": 0}


def test_the_cell_record_s_counts_of_a_sidecar_s_record_line_keep_known_parts_and_counts_only() -> None:
    from armnet_connector.connector import CELL_RECORD_PARTS
    from armnet_node.metrics import AgentMetrics
    from armnet_node.report import CELL_RECORD_PARTS as PARTS_READ
    from armnet_node.report import ConnectorRecord, cell_record_counts
    from armnet_node.runner import count_cell_record

    assert set(PARTS_READ) == set(CELL_RECORD_PARTS)  # the agent reads every part the connector counts
    line = {"trace_rows": {"kept": 120, "dropped": 3}, "video_frames": {"kept": True, "dropped": -1},
            "rollout_pictures": "many", "somethingElse": {"kept": 5}}
    counts = cell_record_counts(line)
    assert counts == {"trace_rows": {"kept": 120, "dropped": 3}, "video_frames": {}}
    assert cell_record_counts(None) == {} and cell_record_counts([1, 2]) == {}

    metrics = AgentMetrics()
    count_cell_record(metrics, ConnectorRecord(cell_record=counts))
    sample = metrics.registry.get_sample_value
    assert sample("armnet_agent_cell_record_items_total", {"part": "trace_rows", "outcome": "kept"}) == 120
    assert sample("armnet_agent_cell_record_items_total", {"part": "trace_rows", "outcome": "dropped"}) == 3

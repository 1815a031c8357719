"""Reading a job pod's status and the connector sidecar's record line (pure parts of the pod launcher)."""

from __future__ import annotations

from typing import Any

import pytest
from armnet_launch.pod import container_state, job_start_delay_s, pod_failed_reason
from armnet_launch.sidecar import parse_record, record_line

pytestmark = pytest.mark.unit


def pod(phase: str = "Running", job: dict[str, Any] | None = None, connector: dict[str, Any] | None = None,
        **status: Any) -> dict[str, Any]:
    return {"status": {
        "phase": phase, **status,
        "containerStatuses": [{"name": "job", "restartCount": 0, **(job or {"state": {"waiting": {}}})}],
        "initContainerStatuses": [{"name": "connector", "restartCount": 0,
                                   **(connector or {"state": {"running": {}}})}],
    }}


def test_a_terminated_job_container_gives_its_exit_code() -> None:
    state = container_state(pod(job={"state": {"terminated": {"exitCode": 3, "reason": "Error"}}}), "job")
    assert state.started and state.exit_code == 3 and state.reason == "Error"


def test_a_waiting_job_container_has_no_exit_code_yet() -> None:
    state = container_state(pod(), "job")
    assert not state.started and state.exit_code is None


def test_the_connectors_restart_count_is_read_from_the_init_container_statuses() -> None:
    state = container_state(pod(connector={"state": {"running": {}}, "restartCount": 2}), "connector")
    assert state.started and state.restarts == 2


def test_the_job_start_delay_is_read_from_the_kubelets_own_times() -> None:
    running = pod(startTime="2026-11-25T06:00:00Z",
                  job={"state": {"running": {"startedAt": "2026-11-25T06:00:41Z"}}})
    assert job_start_delay_s(running) == 41.0
    ended = pod(startTime="2026-11-25T06:00:00Z",
                job={"state": {"terminated": {"exitCode": 0, "startedAt": "2026-11-25T06:00:02Z"}}})
    assert job_start_delay_s(ended) == 2.0


def test_no_job_start_delay_before_the_job_container_runs() -> None:
    assert job_start_delay_s(pod(startTime="2026-11-25T06:00:00Z")) is None
    assert job_start_delay_s(pod(job={"state": {"running": {"startedAt": "garbage"}}})) is None


def test_a_missing_image_is_a_pod_failure_naming_the_reason() -> None:
    assert pod_failed_reason(pod("Pending", job={"state": {"waiting": {"reason": "ErrImageNeverPull"}}})) == \
        "ErrImageNeverPull"


def test_a_pod_failed_by_its_deadline_before_the_job_ran_names_the_reason() -> None:
    assert pod_failed_reason(pod("Failed", reason="DeadlineExceeded")) == "DeadlineExceeded"


def test_a_job_container_that_exited_is_no_pod_failure_even_when_the_pod_failed() -> None:
    failed = pod("Failed", job={"state": {"terminated": {"exitCode": 1}}}, reason="DeadlineExceeded")
    assert pod_failed_reason(failed) is None


def test_the_last_record_line_of_a_connector_log_wins() -> None:
    log = "\n".join(["starting", record_line({"trip_reason": None}), "restarted", record_line({"trip_reason": "x"})])
    assert parse_record(log) == {"trip_reason": "x"}


def test_a_connector_log_without_a_record_line_has_no_record() -> None:
    assert parse_record("serving\nARMNET_CONNECTOR_RECORD not-json\n") is None

"""A preemption as the agent reads it and decides on it: the job's request, the wait, the run's result and status."""

from __future__ import annotations

import logging
from datetime import UTC, datetime, timedelta
from typing import Any

import pytest
from armnet_connector.agent_inputs import MAX_CANCEL_WHY
from armnet_core import JobResult, JobStatus
from armnet_core.resources import PreemptionRequest
from armnet_node.model import parse_job
from armnet_node.preemption import episode_wait_left, preempted_result, preemption_reason
from armnet_node.report import end_detail, terminal_patch

pytestmark = pytest.mark.unit

T0 = datetime(2026, 11, 29, 21, 0, 0, tzinfo=UTC)
MESSAGE = "cell c1 is borrowed by CellQuota 'b'; its owner 'a' has job ns/x waiting"
PREEMPTION = {"requestedAt": "2026-11-29T21:00:00Z", "forJob": "ns/x", "message": MESSAGE, "episodeWaitSeconds": 120}


def a_job(status: dict[str, Any] | None = None, **spec: Any) -> dict[str, Any]:
    return {"metadata": {"name": "job-1", "namespace": "team-a", "uid": "uid-1", "resourceVersion": "9"},
            "spec": {"image": "localhost/pick:1", "embodiment": "lerobot/so-101", "timeoutSeconds": 600, **spec},
            "status": {"phase": "running", "cellName": "c1", **(status or {})}}


def a_request(**fields: Any) -> PreemptionRequest:
    return PreemptionRequest.model_validate({**PREEMPTION, **fields})


def result(status: JobStatus, **fields: Any) -> JobResult:
    return JobResult(status=status, exit_code=fields.pop("exit_code", None), started_at=T0, finished_at=T0, **fields)


# -- the job's request -------------------------------------------------------------------


def test_a_running_jobs_preemption_request_is_read_from_its_status() -> None:
    job = parse_job(a_job({"preemption": PREEMPTION}))
    assert job.preemption is not None
    assert (job.preemption.requested_at, job.preemption.for_job, job.preemption.message,
            job.preemption.episode_wait_seconds) == (T0, "ns/x", MESSAGE, 120)


def test_a_job_without_a_preemption_request_has_none_and_is_requeued_by_default() -> None:
    job = parse_job(a_job())
    assert job.preemption is None and job.requeue_on_preemption is True


def test_a_job_may_ask_not_to_be_requeued_when_preempted() -> None:
    assert parse_job(a_job(requeueOnPreemption=False)).requeue_on_preemption is False


@pytest.mark.parametrize("malformed", [
    {**PREEMPTION, "episodeWaitSeconds": -1},
    {**PREEMPTION, "message": ""},
    {key: value for key, value in PREEMPTION.items() if key != "forJob"},
    {**PREEMPTION, "requestedAt": "yesterday"},
    "preempt now",
])
def test_a_malformed_preemption_request_is_ignored_and_logged_and_the_job_still_parses(
    malformed: Any, caplog: pytest.LogCaptureFixture,
) -> None:
    with caplog.at_level(logging.WARNING, logger="armnet_node.model"):
        job = parse_job(a_job({"preemption": malformed}))
    assert job.preemption is None and job.name == "job-1"
    assert "status.preemption ignored" in caplog.text and "team-a/job-1" in caplog.text


# -- the wait and the reason -------------------------------------------------------------


def test_the_episode_wait_counts_from_the_request_not_from_when_the_agent_saw_it() -> None:
    assert episode_wait_left(a_request(), T0 + timedelta(seconds=30)) == 90.0
    assert episode_wait_left(a_request(), T0 + timedelta(seconds=500)) == 0.0


def test_an_operator_clock_ahead_of_the_agents_never_stretches_the_wait() -> None:
    assert episode_wait_left(a_request(), T0 - timedelta(seconds=60)) == 120.0


def test_the_reason_the_job_is_told_names_the_preemption_within_what_agent_sock_takes() -> None:
    assert preemption_reason(a_request()) == f"preempted: {MESSAGE}"
    long = preemption_reason(a_request(message="m" * 1024))
    assert len(long) == MAX_CANCEL_WHY and long.startswith("preempted: mmm")


# -- the run's result ----------------------------------------------------------------------


def test_a_run_the_preemption_stopped_ends_preempted_with_its_message() -> None:
    ended = preempted_result(result(JobStatus.CANCELLED, return_value={"episodes": 3}), a_request(), stopped=True)
    assert ended.status is JobStatus.PREEMPTED
    assert ended.error == f"preempted: {MESSAGE}"
    assert ended.return_value == {"episodes": 3}  # the partial result is kept


def test_the_full_message_is_the_error_even_when_the_interlocks_reason_was_cut() -> None:
    ended = preempted_result(result(JobStatus.CANCELLED), a_request(message="m" * 1024), stopped=True)
    assert ended.error == "preempted: " + "m" * 1024


@pytest.mark.parametrize("own", [JobStatus.SUCCEEDED, JobStatus.FAILED])
def test_a_job_that_ended_itself_inside_the_preemptions_window_is_preempted_too(own: JobStatus) -> None:
    # Told is_shutting_down at the boundary, it returned (or raised on the refused motion) before the
    # agent's stop reached the supervisor: as in a cancel's window, the stop explains the end.
    assert preempted_result(result(own, exit_code=0), a_request(), stopped=True).status is JobStatus.PREEMPTED


@pytest.mark.parametrize("own", [JobStatus.SUCCEEDED, JobStatus.FAILED, JobStatus.CANCELLED, JobStatus.TIMEOUT])
def test_a_run_the_preemption_did_not_stop_keeps_its_own_result(own: JobStatus) -> None:
    mine = result(own, exit_code=0)
    assert preempted_result(mine, a_request(), stopped=False) == mine


def test_a_timeout_keeps_its_status_whatever_the_preemption_did() -> None:
    mine = result(JobStatus.TIMEOUT)
    assert preempted_result(mine, a_request(), stopped=True) == mine


def test_without_a_preemption_nothing_changes() -> None:
    mine = result(JobStatus.CANCELLED)
    assert preempted_result(mine, None, stopped=True) == mine


# -- the status written and published ----------------------------------------------------------


def test_a_preempted_run_is_written_in_the_preempted_phase_with_its_error() -> None:
    ended = preempted_result(result(JobStatus.CANCELLED, exit_code=0), a_request(), stopped=True)
    patch = terminal_patch("42", ended)
    assert patch["status"]["phase"] == "preempted"
    assert patch["status"]["result"]["error"] == f"preempted: {MESSAGE}"


@pytest.mark.parametrize("requeue", [True, False])
def test_a_preempted_runs_stream_status_says_whether_the_job_goes_back_to_the_queue(requeue: bool) -> None:
    ended = preempted_result(result(JobStatus.CANCELLED, exit_code=0), a_request(), stopped=True)
    detail = end_detail(terminal_patch("42", ended), requeue_on_preemption=requeue)
    assert detail == {"exitCode": 0, "error": f"preempted: {MESSAGE}", "requeue": requeue}


def test_only_a_preempted_runs_stream_status_carries_requeue() -> None:
    detail = end_detail(terminal_patch("42", result(JobStatus.CANCELLED, exit_code=0)), requeue_on_preemption=True)
    assert "requeue" not in detail

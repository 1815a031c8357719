"""armnet_core wire models: validation, ids, JobResult rendering and raise_for_status."""

from __future__ import annotations

import pytest
from armnet_core import (
    BIMANUAL_SO101_EMBODIMENT,
    SO101_EMBODIMENT,
    Job,
    JobResult,
    JobSpec,
    JobStatus,
    RemoteExecutionError,
    TerminalStatus,
)
from pydantic import ValidationError

pytestmark = pytest.mark.unit


def test_embodiment_constants_have_the_documented_values() -> None:
    assert SO101_EMBODIMENT == "lerobot/so-101"
    assert BIMANUAL_SO101_EMBODIMENT == "lerobot/bimanual_so101"


def test_job_spec_defaults() -> None:
    spec = JobSpec(image="img:1", embodiment=SO101_EMBODIMENT)
    assert spec.args == {}
    assert spec.task is None
    assert spec.timeout_seconds == 120
    assert spec.secrets == {}
    assert spec.detach is False
    assert spec.username is None


@pytest.mark.parametrize("missing", ["image", "embodiment"])
def test_job_spec_requires_image_and_embodiment(missing: str) -> None:
    fields = {"image": "img:1", "embodiment": SO101_EMBODIMENT}
    del fields[missing]
    with pytest.raises(ValidationError, match=missing):
        JobSpec(**fields)


@pytest.mark.parametrize("timeout", [0, -5])
def test_job_spec_timeout_must_be_at_least_one_second(timeout: int) -> None:
    with pytest.raises(ValidationError, match="timeout_seconds"):
        JobSpec(image="img", embodiment=SO101_EMBODIMENT, timeout_seconds=timeout)


def test_job_spec_accepts_a_one_second_timeout() -> None:
    assert JobSpec(image="i", embodiment=SO101_EMBODIMENT, timeout_seconds=1).timeout_seconds == 1


def test_jobs_get_unique_ids_and_start_submitted() -> None:
    spec = JobSpec(image="img", embodiment=SO101_EMBODIMENT)
    jobs = [Job(spec=spec) for _ in range(200)]
    assert len({job.id for job in jobs}) == 200
    assert all(job.status is JobStatus.SUBMITTED and not job.is_terminal() for job in jobs)
    assert jobs[0].created_at.tzinfo is not None
    assert jobs[0].cell_id is None and jobs[0].result is None and jobs[0].dispatched is None


def test_terminal_statuses_are_the_seeds_four_end_states_and_preempted() -> None:
    """``PREEMPTED`` is the platform's addition to the seed's four: a run stopped at an episode
    boundary for another job (docs/operator.md, Preemption)."""
    assert TerminalStatus == frozenset(
        {JobStatus.SUCCEEDED, JobStatus.FAILED, JobStatus.TIMEOUT, JobStatus.CANCELLED, JobStatus.PREEMPTED}
    )
    assert Job(spec=JobSpec(image="i", embodiment="e"), status=JobStatus.TIMEOUT).is_terminal()


def test_job_status_values_are_the_wire_strings() -> None:
    assert [s.value for s in JobStatus] == [
        "submitted", "queued", "dispatched", "running",
        "succeeded", "failed", "timeout", "cancelled", "preempted",
    ]
    assert JobStatus("running") is JobStatus.RUNNING


def test_job_result_str_renders_status_value_error_and_indented_traceback() -> None:
    result = JobResult(
        status=JobStatus.FAILED,
        exit_code=1,
        return_value={"a": 1},
        error="image pull failed",
        traceback="Traceback (most recent call last):\nValueError: boom",
    )
    assert str(result) == (
        "JobResult(status=failed, exit_code=1)\n"
        "  return_value: {'a': 1}\n"
        "  error: image pull failed\n"
        "  traceback (from @main):\n"
        "    Traceback (most recent call last):\n"
        "    ValueError: boom"
    )


def test_job_result_str_is_one_line_for_a_bare_success() -> None:
    assert str(JobResult(status=JobStatus.SUCCEEDED)) == "JobResult(status=succeeded)"


def test_raise_for_status_is_a_no_op_on_success() -> None:
    JobResult(status=JobStatus.SUCCEEDED, return_value=3).raise_for_status()


@pytest.mark.parametrize("status", [JobStatus.FAILED, JobStatus.TIMEOUT, JobStatus.CANCELLED])
def test_raise_for_status_raises_remote_execution_error_carrying_the_result(
    status: JobStatus,
) -> None:
    result = JobResult(status=status, error="why")
    with pytest.raises(RemoteExecutionError) as info:
        result.raise_for_status()
    assert info.value.result is result
    assert str(info.value) == str(result)
    assert isinstance(info.value, RuntimeError)


def test_job_round_trips_through_json() -> None:
    job = Job(spec=JobSpec(image="i", embodiment="e", args={"x": [1, 2]}))
    assert Job.model_validate_json(job.model_dump_json()) == job

"""The client's pure mapping: JobSpec -> RobotJob body, RobotJob -> Job / JobResult / table views."""

from __future__ import annotations

import pytest
from armnet_client.mapping import (
    FOLLOWER_TIMEOUT_ANNOTATION,
    cancel_patch,
    cell_view_of,
    generated_name_prefix,
    job_from_robotjob,
    requeue_of,
    result_from_robotjob,
    robotjob_body,
    spec_from_robotjob,
    view_of,
)
from armnet_client.resources import Cell, RobotJob
from armnet_core.api import API_VERSION
from armnet_core.models import JobSpec, JobStatus, RemoteExecutionError

from .builders import a_cell, a_robotjob

pytestmark = pytest.mark.unit


def full_spec() -> JobSpec:
    return JobSpec(image="ghcr.io/acme/pick:1.2", args={"seed": 3, "n": [1, 2]},
                   embodiment="lerobot/so-101", task="pick-cube", timeout_seconds=300,
                   secrets={"HF_TOKEN": "hf-token"}, detach=True, username="mallory")


def test_every_spec_field_maps_one_to_one_onto_the_crd_in_camel_case() -> None:
    body = robotjob_body(full_spec(), namespace="team-a", name="pick-1")

    assert body["apiVersion"] == API_VERSION and body["kind"] == "RobotJob"
    assert body["metadata"] == {"namespace": "team-a", "name": "pick-1"}
    assert body["spec"] == {"image": "ghcr.io/acme/pick:1.2", "args": {"seed": 3, "n": [1, 2]},
                            "embodiment": "lerobot/so-101", "task": "pick-cube",
                            "timeoutSeconds": 300, "secrets": {"HF_TOKEN": "hf-token"},
                            "detach": True}


def test_the_username_is_never_sent_the_platform_knows_the_caller() -> None:
    assert "username" not in robotjob_body(full_spec(), namespace="a")["spec"]


def test_a_spec_without_task_leaves_task_out_so_any_cell_of_the_embodiment_runs_it() -> None:
    spec = JobSpec(image="pick:dev", embodiment="lerobot/so-101")

    assert "task" not in robotjob_body(spec, namespace="a")["spec"]


def test_the_spec_read_back_equals_the_spec_submitted_except_username() -> None:
    spec = full_spec()
    body = robotjob_body(spec, namespace="team-a", name="x")

    back = spec_from_robotjob(RobotJob.model_validate(body))

    assert back == spec.model_copy(update={"username": None})


def test_without_a_name_the_apiserver_generates_one_from_the_image() -> None:
    body = robotjob_body(full_spec(), namespace="a")

    assert body["metadata"]["generateName"] == "pick-"
    assert "name" not in body["metadata"]


@pytest.mark.parametrize(("image", "prefix"), [
    ("ghcr.io/acme/Pick_Cube:1.2", "pick-cube-"),
    ("localhost:5000/team/x@sha256:" + "a" * 64, "x-"),
    ("___:latest", "job-"),
])
def test_generated_prefixes_are_dns_labels(image: str, prefix: str) -> None:
    assert generated_name_prefix(image) == prefix


@pytest.mark.parametrize(("phase", "status"), [
    (None, JobStatus.SUBMITTED), ("queued", JobStatus.QUEUED), ("dispatched", JobStatus.DISPATCHED),
    ("running", JobStatus.RUNNING), ("succeeded", JobStatus.SUCCEEDED), ("failed", JobStatus.FAILED),
    ("timeout", JobStatus.TIMEOUT), ("cancelled", JobStatus.CANCELLED),
])
def test_the_phase_maps_onto_job_status(phase: str | None, status: JobStatus) -> None:
    body = a_robotjob(phase=phase) if phase else a_robotjob()

    assert job_from_robotjob(RobotJob.model_validate(body)).status is status


def test_the_job_id_is_the_robotjob_name_and_cell_id_its_cell() -> None:
    job = job_from_robotjob(RobotJob.model_validate(
        a_robotjob(phase="running", cellName="cell-7", startedAt="2026-11-24T10:00:05Z")))

    assert job.id == "pick-1"
    assert job.cell_id == "cell-7"
    assert job.result is None
    assert job.updated_at.isoformat() == "2026-11-24T10:00:05+00:00"


def test_a_finished_job_carries_its_result_from_the_status() -> None:
    body = a_robotjob(phase="succeeded", startedAt="2026-11-24T10:00:05Z",
                      finishedAt="2026-11-24T10:01:00Z",
                      result={"exitCode": 0, "returnValue": {"success_rate": 1.0},
                              "stdoutTail": "hello\n", "stderrTail": "warn\n"})

    result = job_from_robotjob(RobotJob.model_validate(body)).result

    assert result is not None
    assert result.status is JobStatus.SUCCEEDED
    assert result.exit_code == 0
    assert result.return_value == {"success_rate": 1.0}
    assert (result.stdout, result.stderr) == ("hello\n", "warn\n")
    assert result.finished_at is not None and result.started_at is not None
    result.raise_for_status()


def test_a_finished_job_s_result_says_where_its_output_went() -> None:
    stored = {"phase": "Uploaded", "location": "s3://outputs/team-a/uid-1/",
              "manifest": "s3://outputs/team-a/uid-1/manifest.json", "files": 12, "bytes": 3400,
              "complete": False, "leftOut": 1, "message": "1 entries were not stored: a: changed"}
    result = result_from_robotjob(RobotJob.model_validate(a_robotjob(phase="succeeded", artifacts=stored)))

    assert result is not None and result.artifacts is not None
    assert result.artifacts.model_dump() == {
        "phase": "Uploaded", "location": "s3://outputs/team-a/uid-1/", "manifest": "s3://outputs/team-a/uid-1/manifest.json",
        "files": 12, "bytes": 3400, "complete": False, "left_out": 1, "message": "1 entries were not stored: a: changed"}
    # A job whose agent wrote no output summary (none yet, or no object store and nothing written).
    bare = result_from_robotjob(RobotJob.model_validate(a_robotjob(phase="succeeded")))
    assert bare is not None and bare.artifacts is None


def test_a_failed_job_raises_with_its_traceback() -> None:
    body = a_robotjob(phase="failed", result={"exitCode": 1, "traceback": "Traceback...\nValueError: x"})
    result = result_from_robotjob(RobotJob.model_validate(body))
    assert result is not None

    with pytest.raises(RemoteExecutionError, match="ValueError: x") as raised:
        result.raise_for_status()
    assert raised.value.result.traceback == "Traceback...\nValueError: x"


def test_a_terminal_job_without_a_result_block_still_has_a_result() -> None:
    result = result_from_robotjob(RobotJob.model_validate(a_robotjob(phase="cancelled")))

    assert result is not None and result.status is JobStatus.CANCELLED and result.stdout == ""


def test_a_running_job_has_no_result_yet() -> None:
    assert result_from_robotjob(RobotJob.model_validate(a_robotjob(phase="running"))) is None


def test_unknown_status_fields_from_a_newer_operator_are_ignored() -> None:
    job = RobotJob.model_validate(a_robotjob(phase="queued", somethingNew={"x": 1}))

    assert view_of(job).status is JobStatus.QUEUED


def test_the_view_shows_queue_reason_position_and_rollout() -> None:
    view = view_of(RobotJob.model_validate(a_robotjob(
        phase="queued", queuedReason="AllCellsBusy", queuePosition=3, rollout={"index": 2, "total": 10})))

    assert (view.queued_reason, view.queue_position, view.rollout) == ("AllCellsBusy", 3, (2, 10))


def test_cancel_is_a_merge_patch_of_spec_cancel() -> None:
    assert cancel_patch() == {"spec": {"cancel": True}}


def test_a_cell_view_lists_only_the_false_health_conditions() -> None:
    cell = Cell.model_validate(a_cell(phase="Faulted", currentJob="team-a/pick-1",
                                      lastHeartbeatTime="2026-11-24T10:00:00Z", conditions=[
        {"type": "AgentConnected", "status": "True"},
        {"type": "HardwareReady", "status": "False", "reason": "DeviceLost", "message": "/dev/ttyACM0"},
        {"type": "CamerasReady", "status": "Unknown"}]))

    view = cell_view_of(cell)

    assert view.phase == "Faulted" and view.current_job == "team-a/pick-1"
    assert [(c.type, c.reason) for c in view.false_conditions] == [("HardwareReady", "DeviceLost")]


def test_a_cell_the_operator_never_saw_is_unknown() -> None:
    assert cell_view_of(Cell.model_validate(a_cell())).phase == "Unknown"


def test_a_job_submitted_to_be_followed_declares_its_follower_window() -> None:
    body = robotjob_body(full_spec().model_copy(update={"detach": False}), namespace="a", follower_window_s=12)
    assert body["metadata"]["annotations"] == {FOLLOWER_TIMEOUT_ANNOTATION: "12"}


def test_a_job_submitted_without_a_follower_has_no_follower_annotation() -> None:
    assert "annotations" not in robotjob_body(full_spec(), namespace="a")["metadata"]


def test_a_detached_job_never_declares_a_follower() -> None:
    body = robotjob_body(full_spec().model_copy(update={"detach": True}), namespace="a", follower_window_s=12)
    assert "annotations" not in body["metadata"]


def _preempted(spec: dict[str, object] | None = None, **status: object) -> RobotJob:
    body = a_robotjob(phase="preempted", result={"exitCode": 0, "returnValue": {"episodes_done": 2}}, **status)
    body["spec"].update(spec or {})
    return RobotJob.model_validate(body)


def test_a_preempted_job_names_the_job_that_runs_it_again_once_the_operator_made_it() -> None:
    assert requeue_of(_preempted(requeuedAs="pick-1-r1")) == "pick-1-r1"
    assert requeue_of(_preempted()) == ""  # requeued by default: the operator's next pass creates the copy
    result = job_from_robotjob(_preempted()).result
    assert result is not None and result.status is JobStatus.PREEMPTED
    assert result.return_value == {"episodes_done": 2}  # the partial result stays on the preempted job


@pytest.mark.parametrize("spec", [{"requeueOnPreemption": False}, {"cancel": True}])
def test_no_job_runs_a_preempted_one_again_when_its_spec_or_a_cancel_says_no(spec: dict[str, object]) -> None:
    assert requeue_of(_preempted(spec)) is None


def test_only_a_preempted_job_has_a_requeue() -> None:
    assert requeue_of(RobotJob.model_validate(a_robotjob(phase="succeeded", requeuedAs="x"))) is None

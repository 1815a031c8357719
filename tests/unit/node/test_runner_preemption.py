"""The agent carries out a preemption: the job stops at its next episode boundary, or when the wait runs out.

The runner is not started (no engine, no API server): the job's session is the
container launcher's on a real in-process connector on the simulated SO-101, the
job's side the customer SDK's ``Cell``; ``hooks.on_cancel`` and ``final_result``
are what ``supervise`` and the run call. A pod's channel (``SidecarInputs`` on a
sidecar connector's ``agent.sock``) and the worker's hand-off are here too.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from collections.abc import Iterator
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import pytest
from armnet_core import JobResult, JobStatus
from armnet_launch.cell_spec import resolve_spec
from armnet_launch.sim_cell import LocalCell
from armnet_launch.supervise import SupervisorLimits
from armnet_node.launchers import ContainerSession
from armnet_node.metrics import AgentMetrics
from armnet_node.model import parse_cell, parse_job
from armnet_node.plan import HostPaths
from armnet_node.preemption import STOPPED_AT_EPISODE_END, STOPPED_AT_EPISODE_WAIT
from armnet_node.report import ConnectorRecord
from armnet_node.runner import JobRunner, RunnerDeps
from armnet_node.sidecar_inputs import SidecarInputs
from armnet_node.worker import CellWorker, WorkerSettings
from armnet_runtime.context import Cell
from armnet_sim import SimulatedCellProcess

from tests.support.sidecar_pod import Pod
from tests.support.waiting import wait_for

pytestmark = pytest.mark.unit

MESSAGE = "cell c1 is borrowed by CellQuota 'b'; its owner 'a' has job ns/x waiting"
WHY = f"preempted: {MESSAGE}"
LIMITS = SupervisorLimits(timeout_seconds=600, grace_seconds=30)


def preemption(*, waited_s: float = 0.0, wait_s: int = 120) -> dict[str, Any]:
    """``status.preemption`` as the operator writes it, requested ``waited_s`` ago."""
    at = datetime.now(UTC) - timedelta(seconds=waited_s)
    return {"requestedAt": at.isoformat().replace("+00:00", "Z"), "forJob": "ns/x", "message": MESSAGE,
            "episodeWaitSeconds": wait_s}


def a_job(status: dict[str, Any] | None = None) -> dict[str, Any]:
    return {"metadata": {"name": "job-1", "namespace": "team-a", "uid": "uid-1", "resourceVersion": "9"},
            "spec": {"image": "localhost/pick:1", "embodiment": "lerobot/so-101", "timeoutSeconds": 600},
            "status": {"phase": "running", "cellName": "cell-1", **(status or {})}}


def a_cell() -> dict[str, Any]:
    return {"metadata": {"name": "cell-1", "resourceVersion": "7"},
            "spec": {"embodiment": "lerobot/so-101", "nodeName": "host-1", "simulated": True,
                     "task": "pick", "robot": {"robotId": "follower-1", "safetyLimit": 7.5}},
            "status": {"currentJob": "team-a/job-1"}}


def deps(state_dir: Path) -> RunnerDeps:
    return RunnerDeps(kube=None, launcher=None, paths=HostPaths(state_dir), metrics=AgentMetrics(),
                      link=None, uploads=None)


def runner(state_dir: Path) -> JobRunner:
    """A runner not started: the preemption's wait and stop need no engine and no API server."""
    return JobRunner(parse_job(a_job()), parse_cell(a_cell()), None, deps(state_dir))


def request_of(**kwargs: Any) -> Any:
    request = parse_job(a_job({"preemption": preemption(**kwargs)})).preemption
    assert request is not None
    return request


def supervised(status: JobStatus) -> JobResult:
    """What ``supervise`` returned."""
    now = datetime.now(UTC)
    return JobResult(status=status, exit_code=0, started_at=now, finished_at=now)


@pytest.fixture(scope="module")
def sim() -> Iterator[SimulatedCellProcess]:
    cell = SimulatedCellProcess("so101").start()
    yield cell
    cell.stop()


@pytest.fixture
def local_cell(sim: SimulatedCellProcess) -> Iterator[LocalCell]:
    """The job's in-process connector on the cell's simulator, as the container launcher starts it."""
    # Unix socket paths are limited to 108 bytes: pytest's tmp_path is often longer.
    run_dir = Path(tempfile.mkdtemp(prefix="anp-", dir="/tmp"))
    spec = resolve_spec(embodiment=None, preset="so101", task=None, grace_seconds=30)
    try:
        with LocalCell(spec, run_dir, sim=sim) as cell:
            yield cell
    finally:
        shutil.rmtree(run_dir, ignore_errors=True)


def session_on(cell: LocalCell) -> ContainerSession:
    # The preemption reaches only the cell's connector: neither the engine nor the request is needed.
    return ContainerSession(None, None, cell)  # type: ignore[arg-type]


def the_job(cell: LocalCell) -> Cell:
    """The job's SDK handle on its operator socket."""
    assert cell.connector is not None
    return Cell(operator_call_endpoint=cell.connector.operator_endpoint)


def trip_message(cell: LocalCell) -> str | None:
    assert cell.connector is not None
    trip = cell.connector.interlock.trip_info
    return trip.message if trip is not None else None


def stopping(job: JobRunner) -> bool:
    return job.hooks.cancel_gracefully.is_set()


# -- the container launcher's in-process connector ---------------------------------------------


def test_between_rollouts_the_job_is_stopped_at_once_and_ends_preempted(tmp_path: Path, local_cell: LocalCell) -> None:
    job, session = runner(tmp_path), session_on(local_cell)
    job.session_started(session)
    job.preempt(request_of())

    wait_for(lambda: stopping(job), timeout=10, what="the graceful stop")
    assert job.preemption_stopped_at == STOPPED_AT_EPISODE_END
    assert the_job(local_cell).is_shutting_down() is True
    assert trip_message(local_cell) == WHY
    job.hooks.on_cancel()  # supervise opens the window: open already, its reason stays the preemption's
    assert trip_message(local_cell) == WHY

    ended = job.final_result(supervised(JobStatus.CANCELLED), None, job.settle_device_loss(), session.record(), LIMITS)
    assert ended.status is JobStatus.PREEMPTED and ended.error == WHY


def test_during_a_rollout_the_job_runs_on_until_that_rollouts_end(tmp_path: Path, local_cell: LocalCell) -> None:
    job, session = runner(tmp_path), session_on(local_cell)
    job.session_started(session)
    the_job(local_cell).rollout_begin(index=2, total=5)
    job.preempt(request_of())

    time.sleep(0.5)  # five checks of the boundary
    assert not stopping(job) and the_job(local_cell).is_shutting_down() is False
    the_job(local_cell).rollout_end()
    wait_for(lambda: stopping(job), timeout=10, what="the graceful stop at the rollout's end")
    assert job.preemption_stopped_at == STOPPED_AT_EPISODE_END
    assert the_job(local_cell).is_shutting_down() is True and trip_message(local_cell) == WHY


def test_without_a_boundary_within_the_wait_the_agent_opens_the_grace_window_itself(
    tmp_path: Path, local_cell: LocalCell,
) -> None:
    job, session = runner(tmp_path), session_on(local_cell)
    job.session_started(session)
    the_job(local_cell).rollout_begin(index=0, total=1)
    job.preempt(request_of(waited_s=119, wait_s=120))  # requested 119 s ago: one second is left

    wait_for(lambda: stopping(job), timeout=10, what="the graceful stop when the wait ran out")
    assert job.preemption_stopped_at == STOPPED_AT_EPISODE_WAIT
    assert the_job(local_cell).is_shutting_down() is False  # the episode still runs, until supervise opens the window
    job.hooks.on_cancel()
    assert the_job(local_cell).is_shutting_down() is True and trip_message(local_cell) == WHY

    ended = job.final_result(supervised(JobStatus.CANCELLED), None, job.settle_device_loss(), session.record(), LIMITS)
    assert ended.status is JobStatus.PREEMPTED and ended.error == WHY


def test_a_preemption_asked_before_the_job_started_reaches_its_connector_once_it_did(
    tmp_path: Path, local_cell: LocalCell,
) -> None:
    job = runner(tmp_path)
    job.preempt(request_of())
    time.sleep(0.3)
    assert not stopping(job) and trip_message(local_cell) is None
    job.session_started(session_on(local_cell))
    wait_for(lambda: stopping(job), timeout=10, what="the graceful stop once the job started")
    assert trip_message(local_cell) == WHY


def test_a_second_preemption_changes_nothing(tmp_path: Path, local_cell: LocalCell) -> None:
    job = runner(tmp_path)
    first = request_of()
    job.preempt(first)
    job.preempt(request_of(waited_s=1000))
    assert job.preemption is first
    job.session_started(session_on(local_cell))
    wait_for(lambda: stopping(job), timeout=10, what="the graceful stop")
    assert job.preemption_stopped_at == STOPPED_AT_EPISODE_END  # the second's spent wait did not count


def test_a_job_that_ended_before_the_boundary_keeps_its_own_result(tmp_path: Path, local_cell: LocalCell) -> None:
    job, session = runner(tmp_path), session_on(local_cell)
    job.session_started(session)
    the_job(local_cell).rollout_begin(index=0, total=1)
    job.preempt(request_of())
    time.sleep(0.3)
    mine = supervised(JobStatus.SUCCEEDED)  # it returned inside its last episode

    ended = job.final_result(mine, None, job.settle_device_loss(), session.record(), LIMITS)
    assert ended == mine
    time.sleep(0.3)
    assert not stopping(job)  # the job's end also ends the wait


def test_a_job_that_returned_in_the_window_the_boundary_opened_ends_preempted(
    tmp_path: Path, local_cell: LocalCell,
) -> None:
    # The job ended on its own right after the boundary, before the agent's stop reached the supervisor:
    # the connector's record says the preemption opened its grace window.
    job, session = runner(tmp_path), session_on(local_cell)
    job.preempt(request_of())  # no session yet: the agent's stop cannot begin
    assert local_cell.connector is not None
    assert local_cell.connector.cell.stop_at_episode_end(WHY) is True

    ended = job.final_result(supervised(JobStatus.SUCCEEDED), None, job.settle_device_loss(), session.record(), LIMITS)
    assert ended.status is JobStatus.PREEMPTED and ended.error == WHY


@pytest.mark.parametrize("cancel", ["before the preemption", "after its stop began"])
def test_a_cancel_keeps_the_run_cancelled(tmp_path: Path, local_cell: LocalCell, cancel: str) -> None:
    job, session = runner(tmp_path), session_on(local_cell)
    job.session_started(session)
    if cancel == "before the preemption":
        job.stop()
    job.preempt(request_of())
    if cancel == "after its stop began":
        wait_for(lambda: job.preemption_stopped_at is not None, timeout=10, what="the preemption's stop")
        job.stop()
    time.sleep(0.3)

    ended = job.final_result(supervised(JobStatus.CANCELLED), None, job.settle_device_loss(), session.record(), LIMITS)
    assert ended.status is JobStatus.CANCELLED  # a cancelled job never goes back to the queue


def test_an_infrastructure_failure_and_a_lost_device_keep_their_precedence(tmp_path: Path) -> None:
    job = runner(tmp_path)
    job.preempt(request_of(waited_s=1000))  # the wait ran out: the agent's stop begins at once
    wait_for(lambda: stopping(job), timeout=10, what="the graceful stop")
    record = ConnectorRecord(trip_reason="deadline", trip_message=WHY)

    oom = job.final_result(supervised(JobStatus.FAILED), "the container was killed for exceeding its memory limit "
                           "(OOM)", None, record, LIMITS)
    assert oom.status is JobStatus.FAILED and "OOM" in (oom.error or "")
    lost = job.final_result(supervised(JobStatus.CANCELLED), None, "device lost: arm", record, LIMITS)
    assert lost.status is JobStatus.FAILED and lost.error == "device lost: arm"
    preempted = job.final_result(supervised(JobStatus.CANCELLED), None, None, record, LIMITS)
    assert preempted.status is JobStatus.PREEMPTED and job.preemption_stopped_at == STOPPED_AT_EPISODE_WAIT


# -- a pod's sidecar connector, through agent.sock ---------------------------------------------


@pytest.fixture
def pod(sim: SimulatedCellProcess) -> Iterator[Pod]:
    pod = Pod(sim, grace_period_seconds=30.0)
    yield pod
    pod.close()


def test_a_pods_connector_is_asked_through_agent_sock_and_tells_when_the_boundary_came(pod: Pod) -> None:
    metrics = AgentMetrics()
    inputs = SidecarInputs(lambda: pod.agent_path, metrics)
    job = pod.job_cell()
    job.rollout_begin(index=0, total=2)

    assert inputs.preempt(WHY) is False  # the window opens at the end of the open rollout
    assert inputs.preempt_window_open(WHY) is False and job.is_shutting_down() is False
    job.rollout_end()
    assert inputs.preempt_window_open(WHY) is True and job.is_shutting_down() is True
    trip = pod.connector.interlock.trip_info
    assert trip is not None and trip.message == WHY
    # The request is counted once; the polls are not inputs.
    assert metrics.registry.get_sample_value(
        "armnet_agent_sidecar_inputs_total", {"op": "preempt", "result": "applied"}) == 1


def test_a_preemption_that_cannot_reach_the_sidecar_is_counted_failed(tmp_path: Path) -> None:
    metrics = AgentMetrics()
    inputs = SidecarInputs(lambda: tmp_path / "agent.sock", metrics)
    assert inputs.preempt(WHY) is None and inputs.preempt_window_open(WHY) is False
    assert metrics.registry.get_sample_value(
        "armnet_agent_sidecar_inputs_total", {"op": "preempt", "result": "failed"}) == 1


# -- the worker hands the request to the runner ----------------------------------------------------


def test_the_worker_hands_a_running_jobs_preemption_to_its_runner_once(tmp_path: Path) -> None:
    worker = CellWorker(parse_cell(a_cell()), deps(tmp_path), WorkerSettings())
    worker.runner = job = runner(tmp_path)
    preempted = parse_job(a_job({"preemption": preemption(waited_s=1000)}))

    worker.observe([preempted], {})
    worker.observe([parse_job(a_job({"preemption": {**preemption(), "message": "another"}}))], {})

    assert job.preemption == preempted.preemption
    wait_for(lambda: stopping(job), timeout=10, what="the graceful stop")  # the wait had run out already
    assert job.preemption_stopped_at == STOPPED_AT_EPISODE_WAIT


def test_the_worker_cancels_rather_than_preempts_a_job_being_cancelled(tmp_path: Path) -> None:
    worker = CellWorker(parse_cell(a_cell()), deps(tmp_path), WorkerSettings())
    worker.runner = job = runner(tmp_path)
    cancelled = a_job({"preemption": preemption(waited_s=1000)})
    cancelled["spec"]["cancel"] = True

    worker.observe([parse_job(cancelled)], {})

    assert stopping(job) and job.preemption is None

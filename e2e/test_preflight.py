"""Pre-flight on a simulated twin, end to end: a job that trips the interlock never costs real cell time.

Real kube-apiserver + etcd, the real ``armnet operator`` and ``armnet agent``, Podman
containers, the cell simulator driven by LeRobot's own Feetech bus through the connector.
The bed has one ordinary cell and one pre-flight cell (``spec.preflight: true``, a
simulated twin) of the same embodiment on one node. A job with ``spec.preflight`` first
runs as its pre-flight RobotJob on the twin: one that makes an unsafe move at once fails
there (the connector refuses the move and trips the interlock), so the job fails with
``PreflightFailed`` and never binds the ordinary cell; a good one passes its pre-flight
and then runs on the ordinary cell.
"""

from __future__ import annotations

from collections.abc import Iterator
from datetime import datetime
from typing import Any

import pytest

from e2e.agent_bed import EXAMPLES, JOBS, AgentBed, JobWatch
from e2e.scenarios import explain, moment_of, status

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(600)]


def whole_seconds(value: str) -> datetime:
    """A status time the agent wrote (milliseconds) at the operator's precision (seconds, ``metav1.Time``)."""
    return moment_of(value).replace(microsecond=0)


class TwinBed(AgentBed):
    """The bed with an ordinary cell (``real``) and a pre-flight twin (``twin``) of one embodiment."""

    real: str
    twin: str

    def events_of(self, name: str) -> list[str]:
        from kubernetes import client

        core = client.CoreV1Api(self.objects.api_client)
        found = core.list_namespaced_event(self.namespace, field_selector=f"involvedObject.name={name}")
        return [event.reason for event in found.items]


@pytest.fixture(scope="module")
def bed(k8s: Any, podman: Any, base_image: str) -> Iterator[TwinBed]:
    namespace = k8s.create_namespace("preflight")
    bed = TwinBed(k8s, podman, base_image, namespace)
    bed.real = bed.add_cell("so101")
    bed.twin = bed.add_cell("twin", preflight=True)
    bed.start_operator()
    bed.start_agent()
    try:
        bed.wait_ready(bed.real, timeout=90)
        bed.wait_ready(bed.twin, timeout=90)
        yield bed
    finally:
        bed.stop()
        k8s.delete_namespace(namespace)


@pytest.fixture()
def watch(bed: TwinBed) -> Iterator[JobWatch]:
    seen = JobWatch(bed.k8s, bed.namespace)
    try:
        yield seen
    finally:
        seen.close()


def test_a_job_that_trips_the_interlock_fails_in_its_preflight_and_never_binds_a_real_cell(
        bed: TwinBed, watch: JobWatch) -> None:
    unsafe = bed.image("unsafe", JOBS / "unsafe.py", (EXAMPLES / "_so101_moves.py",))
    # A bound well above the job's start-up (the LeRobot import took 40 s and more on a loaded
    # 2-core host): the unsafe move, not the bound, must end the pre-flight.
    bed.submit("unsafe", unsafe, timeout=180, preflight={"seconds": 150})
    held_by: set[str] = set()

    def failed() -> dict[str, Any] | None:
        held_by.add(str((bed.cell(bed.real).get("status") or {}).get("currentJob")))
        job = bed.job("unsafe")
        return job if status(job).get("phase") in ("failed", "succeeded", "timeout", "cancelled") else None

    parent = status(bed.wait(failed, 300, "job unsafe to end"))
    assert parent["phase"] == "failed", explain(parent)
    assert parent["preflight"]["phase"] == "Failed", parent["preflight"]
    name = parent["preflight"]["job"]
    assert name == "unsafe-preflight"
    assert parent["result"]["error"].startswith("pre-flight failed: "), parent["result"]
    assert name in parent["result"]["error"]
    queued = next(c for c in parent["conditions"] if c["type"] == "Queued")
    assert (queued["status"], queued["reason"]) == ("False", "PreflightFailed")

    child = status(bed.job(name))
    assert child["phase"] == "failed", explain(child)
    assert child["cellName"] == bed.twin
    assert "SafetyViolation" in child["result"]["traceback"]
    assert child["result"]["safety"]["interlockTrips"] >= 1, child["result"]["safety"]
    assert moment_of(parent["preflight"]["finishedAt"]) >= whole_seconds(child["finishedAt"])

    # Never bound to the ordinary cell: no status of the job ever named a cell, nor the cell the job.
    seen = watch.statuses("unsafe")
    assert seen and not any(s.get("cellName") for s in seen), seen
    assert not any(s.get("phase") in ("dispatched", "running") for s in seen), seen
    assert any(s.get("queuedReason") == "PreflightRunning" for s in seen), seen
    assert f"{bed.namespace}/unsafe" not in held_by, held_by
    # Events go out from a background poster, a moment after the writes they tell of.
    bed.wait(lambda: {"PreflightStarted", "PreflightFailed"} <= set(bed.events_of("unsafe")), 30,
             "the PreflightStarted and PreflightFailed Events on job unsafe")


def test_a_good_job_binds_the_real_cell_once_its_preflight_passed(bed: TwinBed, watch: JobWatch) -> None:
    episodes = bed.image("episodes", JOBS / "episodes.py", (EXAMPLES / "_so101_moves.py",))
    # Twelve rollouts of ~0.8 s on the arm: the 10 s pre-flight usually runs its whole time
    # (timeout: it passes, having moved the twin), then the job runs to its end on the ordinary cell.
    bed.submit("good", episodes, timeout=120, args={"episodes": 12, "hold": 0.5}, preflight={"seconds": 10})

    parent = status(bed.wait_phase("good", timeout=240))
    assert parent["phase"] == "succeeded", explain(parent)
    assert parent["cellName"] == bed.real
    assert parent["preflight"]["phase"] == "Passed", parent["preflight"]
    assert parent["result"]["returnValue"] == {"episodes_done": 12, "of": 12, "refused_mid_rollout": []}

    child = status(bed.job(parent["preflight"]["job"]))
    assert child["phase"] in ("succeeded", "timeout"), explain(child)
    assert child["cellName"] == bed.twin
    assert child["result"]["safety"]["deviceCalls"] > 0, child["result"]["safety"]
    if child["phase"] == "timeout":
        assert "without failing" in parent["preflight"]["message"]
        assert "call(s) to the twin's devices" in parent["preflight"]["message"]
    # The job started on the real cell only after its pre-flight ended and the verdict was written.
    assert moment_of(parent["startedAt"]) >= moment_of(parent["preflight"]["finishedAt"])
    assert moment_of(parent["preflight"]["finishedAt"]) >= whole_seconds(child["finishedAt"])
    seen = watch.statuses("good")
    waiting = [s for s in seen if s.get("queuedReason") == "PreflightRunning"]
    assert waiting and not any(s.get("cellName") for s in waiting), seen
    bed.wait(lambda: {"PreflightStarted", "PreflightPassed"} <= set(bed.events_of("good")), 30,
             "the PreflightStarted and PreflightPassed Events on job good")

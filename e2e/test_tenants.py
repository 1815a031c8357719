"""Preemption only at an episode boundary, end to end: two tenants, one cell, the real processes.

Real kube-apiserver + etcd, the real ``armnet operator`` and ``armnet agent``, Podman
containers, the cell simulator driven by LeRobot's own Feetech bus through the connector.
Tenant A owns the cell (a CellQuota of one nominal cell); tenant B has none and borrows it
from their cohort while A has nothing to run. When A submits, B's job must give the cell
back: the operator asks for a stop at B's next episode boundary, B's open rollout ends with
no move refused, B ends ``preempted`` with how far it got, A runs on the cell, and a copy
of B's job (keeping B's place in the queue) runs B's work again once A is done.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest
import yaml
from armnet_core.api import API_VERSION, GROUP, PREEMPTED_FROM_ANNOTATION, ROBOTJOBS, VERSION

from e2e.agent_bed import EXAMPLES, JOBS, AgentBed
from e2e.scenarios import explain, moment_of, status

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(600)]

EPISODES = 6


class Tenants(AgentBed):
    """The bed with a second namespace, tenant B's, watched by its operator and agent."""

    def __init__(self, *args: Any, other: str, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.other = other
        watched = f"{self.namespace},{other}"
        self.operator_args = ["--namespaces", watched]
        self.agent_args = ["--namespaces", watched]

    def job_of(self, namespace: str, name: str) -> dict[str, Any]:
        job: dict[str, Any] = self.objects.get_namespaced_custom_object(GROUP, VERSION, namespace, ROBOTJOBS, name)
        return job

    def submit_to(self, namespace: str, name: str, image: str, **spec: Any) -> None:
        body = {"image": image, "embodiment": "lerobot/so-101", "task": self.node, **spec}
        self.k8s.kubectl("apply", "-n", namespace, "-f", "-", input=yaml.safe_dump(
            {"apiVersion": API_VERSION, "kind": "RobotJob", "metadata": {"name": name}, "spec": body}))

    def phase_of(self, namespace: str, name: str, phases: tuple[str, ...], timeout: float) -> dict[str, Any]:
        def reached() -> dict[str, Any] | None:
            job = self.job_of(namespace, name)
            return job if status(job).get("phase") in phases else None
        return self.wait(reached, timeout, f"{namespace}/{name} to reach {phases}")

    def events_of(self, namespace: str, name: str) -> list[str]:
        from kubernetes import client

        core = client.CoreV1Api(self.objects.api_client)
        found = core.list_namespaced_event(namespace, field_selector=f"involvedObject.name={name}")
        return [event.reason for event in found.items]


def quota(name: str, namespace: str, nominal: int, task: str) -> dict[str, Any]:
    return {"apiVersion": API_VERSION, "kind": "CellQuota", "metadata": {"name": name},
            "spec": {"namespace": namespace, "embodiment": "lerobot/so-101", "task": task,
                     "nominalCells": nominal, "cohort": f"lab-{task}"}}


@pytest.fixture(scope="module")
def bed(k8s: Any, podman: Any, base_image: str, nats_server: str) -> Iterator[Tenants]:
    owner, borrower = k8s.create_namespace("preempt-a"), k8s.create_namespace("preempt-b")
    bed = Tenants(k8s, podman, base_image, owner, nats_url=nats_server, other=borrower)
    cell = bed.add_cell("so101")
    quotas = [quota(f"a-{bed.node}", owner, 1, bed.node), quota(f"b-{bed.node}", borrower, 0, bed.node)]
    for body in quotas:
        bed.apply(body, namespaced=False)
    bed.start_operator()
    bed.start_agent()
    try:
        bed.wait_ready(cell, timeout=90)
        yield bed
    finally:
        bed.stop()
        for body in quotas:
            k8s.kubectl("delete", "cellquota", body["metadata"]["name"], "--ignore-not-found", "--wait=false",
                        check=False)
        k8s.delete_namespace(owner)
        k8s.delete_namespace(borrower)


def test_a_borrowed_cell_goes_back_at_an_episode_boundary_and_the_preempted_job_runs_again(bed: Tenants) -> None:
    episodes = bed.image("episodes", JOBS / "episodes.py", (EXAMPLES / "_so101_moves.py",))
    echo = bed.image("echo", JOBS / "echo.py")
    bed.submit_to(bed.other, "borrower", episodes, timeoutSeconds=300, args={"episodes": EPISODES, "hold": 1.0})
    bed.wait(lambda: any(r.get("endedAt") for r in status(bed.job_of(bed.other, "borrower")).get("rollouts") or []),
             240, "the borrower to end its first rollout on the borrowed cell")
    bed.submit_to(bed.namespace, "owner", echo, timeoutSeconds=120)

    borrowed = status(bed.phase_of(bed.other, "borrower", ("preempted", "succeeded", "failed", "timeout"), 120))
    assert borrowed["phase"] == "preempted", explain(borrowed)
    request = borrowed["preemption"]
    assert request["forJob"] == f"{bed.namespace}/owner"
    assert f"b-{bed.node}" in request["message"]
    partial = borrowed["result"]["returnValue"]
    assert partial["refused_mid_rollout"] == [], partial  # stopped at an episode boundary, never mid-move
    assert 1 <= partial["episodes_done"] < EPISODES, partial
    rollouts = borrowed["rollouts"]
    assert len(rollouts) == partial["episodes_done"] and all(r.get("endedAt") for r in rollouts), rollouts
    assert borrowed["result"]["error"].startswith("preempted: "), borrowed["result"]
    assert moment_of(borrowed["finishedAt"]) >= moment_of(request["requestedAt"])

    owner = status(bed.phase_of(bed.namespace, "owner", ("succeeded", "failed"), 180))
    assert owner["phase"] == "succeeded", explain(owner)
    assert owner["cellName"] == borrowed["cellName"]
    assert moment_of(owner["startedAt"]) >= moment_of(borrowed["finishedAt"])

    copy_name = bed.wait(lambda: status(bed.job_of(bed.other, "borrower")).get("requeuedAs"), 60,
                         "the preempted job's copy")
    copy = bed.phase_of(bed.other, copy_name, ("succeeded", "failed", "timeout", "preempted"), 240)
    original = bed.job_of(bed.other, "borrower")
    assert copy["metadata"]["annotations"][PREEMPTED_FROM_ANNOTATION] == original["metadata"]["uid"]
    assert status(copy)["phase"] == "succeeded", explain(status(copy))
    assert status(copy)["result"]["returnValue"]["episodes_done"] == EPISODES
    assert "Preempted" in bed.events_of(bed.other, "borrower")
    assert "Requeued" in bed.events_of(bed.other, "borrower")
    assert "Preempting" in bed.events_of(bed.namespace, "owner")

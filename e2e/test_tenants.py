"""Two tenants on shared cells, end to end: fair share by weight, and preemption only at an episode boundary.

Real kube-apiserver + etcd, the real ``armnet operator`` and ``armnet agent``, Podman
containers, the cell simulator driven by LeRobot's own Feetech bus through the connector.
One bed, two tenants (namespaces), two groups of cells told apart by task:

- four shared cells, where each tenant's CellQuota gives it all four (nominal shares
  above the cells: every pass ranks the tenants by weighted usage alone) and A weighs
  three times B: while both have jobs waiting, A gets three quarters of the cell time;
- one cell A owns (a CellQuota of one nominal cell) and B may borrow from their cohort
  while A has nothing to run. When A submits, B's job must give the cell back: the
  operator asks for a stop at B's next episode boundary, B's open rollout ends with no
  move refused, B ends ``preempted`` with how far it got, A runs on the cell, and a copy
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
#: Fair share: A weighs 3, B 1; 40 jobs of 1.5 s on four cells (A 30, B 10: under fair share both
#: queues drain together; first-come would run B's ten in the first half).
WEIGHTS = (3, 1)
JOBS_PER_TENANT = (30, 10)
SHARED = "shared"


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


def quota(name: str, namespace: str, nominal: int, task: str, **spec: Any) -> dict[str, Any]:
    return {"apiVersion": API_VERSION, "kind": "CellQuota", "metadata": {"name": name},
            "spec": {"namespace": namespace, "embodiment": "lerobot/so-101", "task": task,
                     "nominalCells": nominal, **spec}}


@pytest.fixture(scope="module")
def bed(k8s: Any, podman: Any, base_image: str, nats_server: str) -> Iterator[Tenants]:
    owner, borrower = k8s.create_namespace("preempt-a"), k8s.create_namespace("preempt-b")
    bed = Tenants(k8s, podman, base_image, owner, nats_url=nats_server, other=borrower)
    shared_task = f"{SHARED}-{bed.node}"
    cells = [bed.add_cell("so101")] + [bed.add_cell(f"shared{i}", task=shared_task) for i in range(4)]
    cohort = f"lab-{bed.node}"
    quotas = [quota(f"a-{bed.node}", owner, 1, bed.node, cohort=cohort),
              quota(f"b-{bed.node}", borrower, 0, bed.node, cohort=cohort),
              quota(f"a-{shared_task}", owner, 4, shared_task, weight=WEIGHTS[0]),
              quota(f"b-{shared_task}", borrower, 4, shared_task, weight=WEIGHTS[1])]
    for body in quotas:
        bed.apply(body, namespaced=False)
    bed.start_operator()
    bed.start_agent()
    try:
        for cell in cells:
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


def test_while_both_tenants_wait_each_gets_cell_time_in_proportion_to_its_weight(bed: Tenants) -> None:
    counts = bed.image("counts", JOBS / "counts_slowly.py")
    task = f"{SHARED}-{bed.node}"
    names = {bed.namespace: [f"a{i:02d}" for i in range(JOBS_PER_TENANT[0])],
             bed.other: [f"b{i:02d}" for i in range(JOBS_PER_TENANT[1])]}
    for a, b in zip(names[bed.namespace], names[bed.other] + [None] * 20, strict=False):
        for namespace, name in ((bed.namespace, a), (bed.other, b)):
            if name is not None:
                bed.submit_to(namespace, name, counts, task=task, timeoutSeconds=120,
                              args={"lines": 3, "pause": 0.5})
    runs = {(namespace, name): status(bed.phase_of(namespace, name, ("succeeded", "failed", "timeout"), 400))
            for namespace, jobs in names.items() for name in jobs}
    assert all(st["phase"] == "succeeded" for st in runs.values()), {k: explain(v) for k, v in runs.items()
                                                                     if v["phase"] != "succeeded"}
    spans = {key: (moment_of(st["startedAt"]), moment_of(st["finishedAt"])) for key, st in runs.items()}
    # The window in which both tenants had a job waiting: until the last job of either started.
    last_start = {ns: max(spans[(ns, n)][0] for n in jobs) for ns, jobs in names.items()}
    start, end = min(s for s, _ in spans.values()), min(last_start.values())
    held = {ns: sum(max(0.0, (min(e, end) - max(s, start)).total_seconds())
                    for (job_ns, _), (s, e) in spans.items() if job_ns == ns) for ns in names}
    share = held[bed.namespace] / (held[bed.namespace] + held[bed.other])
    wanted = WEIGHTS[0] / sum(WEIGHTS)
    assert abs(share - wanted) <= 0.10, (share, held, end - start)

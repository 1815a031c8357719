"""Preemption at an episode boundary, as the operator decides and writes it.

A borrowed cell goes back to the tenant that owns it: the reconcile pass asks the
borrowing job to stop at its next episode boundary (``status.preemption``, the node
agent carries it out), says so in an Event on both jobs, and asks only once. A job
that ended ``preempted`` is run again by a copy that keeps its place in the queue,
created once even across a crash.
"""

from __future__ import annotations

from dataclasses import replace
from datetime import timedelta
from typing import Any

import pytest
from armnet_core.api import PREEMPTED_FROM_ANNOTATION, QUEUED_SINCE_ANNOTATION
from armnet_core.times import kube_time
from armnet_operator.lifecycle import DeleteJob, RequeuePreempted, plan_lifecycle
from armnet_operator.model import JobPhase
from armnet_operator.parsing import parse_job
from armnet_operator.quota_parsing import read_quota
from armnet_operator.reconcile import Memory, Outcome, reconcile_once
from armnet_operator.requeue import requeue_body, requeue_name
from operator_builders import NOW, TIMING, a_job, ago

from tests.unit.operator.operator_world import World
from tests.unit.operator.test_fairshare_wiring import LIMITS, quota_body

pytestmark = pytest.mark.unit

COHORT = [quota_body("a", "t", 1), quota_body("b", "t2", 0)]
for body in COHORT:
    body["spec"]["cohort"] = "lab"


def borrowed_world() -> World:
    """Tenant b (no cells of its own) borrows the lab's only cell, which tenant a owns."""
    world = World()
    world.add_cell("c1", "so101", None)
    world.submit("b1", "so101", None, 0)
    world.jobs["t2/b1"] = world.jobs.pop("t/b1")
    world.jobs["t2/b1"]["metadata"]["namespace"] = "t2"
    return world


def run(world: World, memory: Memory) -> Outcome:
    for body in COHORT:
        world.quotas.setdefault(body["metadata"]["name"], body)
    for cell in world.cells:
        world.heartbeat(cell)
    jobs, cells = world.snapshot()
    quotas = [read_quota(b) for b in world.quotas.values()]
    return reconcile_once(jobs, cells, world.now, TIMING, world, memory, LIMITS, quotas)


def agent_runs(world: World, key: str) -> None:
    world.agent_set_phase(key, "running")
    world.jobs[key]["status"]["startedAt"] = kube_time(world.now)


def test_an_owner_waiting_for_its_borrowed_cell_preempts_the_borrower_once_with_events_on_both() -> None:
    world, memory = borrowed_world(), Memory()
    run(world, memory)
    assert world.jobs["t2/b1"]["status"]["phase"] == "dispatched"  # borrowed: a owns the lab's only cell
    agent_runs(world, "t2/b1")
    world.tick(5)
    world.submit("a1", "so101", None, 0)
    outcome = run(world, memory)
    request = world.jobs["t2/b1"]["status"]["preemption"]
    assert request["forJob"] == "t/a1"
    assert "CellQuota 'b'" in request["message"] and "'a'" in request["message"]
    assert request["episodeWaitSeconds"] == int(TIMING.episode_wait.total_seconds())
    assert outcome.preempted == {"reclaim": 1}
    assert ("t2/b1", "Preempted") in world.events and ("t/a1", "Preempting") in world.events
    assert world.jobs["t/a1"]["status"]["queuedReason"] == "AllCellsBusy"
    world.tick(5)
    again = run(world, memory)  # the borrower is still running to its episode boundary
    assert again.preempted == {}
    assert world.events.count(("t2/b1", "Preempted")) == 1


def test_a_preempted_job_is_run_again_by_a_copy_that_keeps_its_place_and_the_owner_gets_the_cell() -> None:
    world, memory = borrowed_world(), Memory()
    world.jobs["t2/b1"]["metadata"]["labels"] = {"team": "vision"}
    world.jobs["t2/b1"]["spec"]["args"] = {"episodes": 3}
    run(world, memory)
    agent_runs(world, "t2/b1")
    world.tick(5)
    world.submit("a1", "so101", None, 0)
    run(world, memory)
    world.tick(5)
    world.agent_set_phase("t2/b1", "preempted")  # the node agent: episode ended, grace window, partial result
    outcome = run(world, memory)
    original = world.jobs["t2/b1"]
    assert original["status"]["phase"] == "preempted"
    assert original["status"]["requeuedAs"] == "b1-r1"
    copy = world.jobs["t2/b1-r1"]
    assert copy["spec"]["args"] == {"episodes": 3} and copy["spec"]["cancel"] is False
    assert copy["metadata"]["labels"] == {"team": "vision"}
    assert copy["metadata"]["annotations"][PREEMPTED_FROM_ANNOTATION] == original["metadata"]["uid"]
    assert parse_job(copy).created == parse_job(original).created  # its place in the queue
    assert outcome.requeued_copies == 1
    assert ("t2/b1", "Requeued") in world.events and ("t2/b1-r1", "RequeuedFrom") in world.events
    assert world.cells["c1"]["status"].get("currentJob") in (None, "t/a1")
    world.tick(1)
    run(world, memory)
    assert world.jobs["t/a1"]["status"]["phase"] == "dispatched"  # the owner's job has its cell
    assert world.jobs["t2/b1-r1"]["status"]["phase"] == "queued"
    assert "t2/b1-r2" not in world.jobs  # created once


def test_a_copy_created_before_a_crash_is_found_not_created_twice() -> None:
    world = World()
    world.submit("b1", "so101", None, 0)
    world.agent_set_phase("t/b1", "preempted")
    preempted = world.read_job("t", "b1")
    world.create_job(requeue_body(preempted, "b1-r1", NOW))  # the crash came before status.requeuedAs
    run(world, Memory())
    assert world.jobs["t/b1"]["status"]["requeuedAs"] == "b1-r1"
    assert sorted(world.jobs) == ["t/b1", "t/b1-r1"]


def test_a_tenants_own_job_with_the_copys_name_is_left_alone() -> None:
    world = World()
    world.submit("b1", "so101", None, 0)
    world.submit("b1-r1", "so101", None, 0)
    world.agent_set_phase("t/b1", "preempted")
    run(world, Memory())
    name = world.jobs["t/b1"]["status"]["requeuedAs"]
    assert name == "b1-r1-uid-b1"
    assert PREEMPTED_FROM_ANNOTATION not in (world.jobs["t/b1-r1"]["metadata"].get("annotations") or {})


@pytest.mark.parametrize("change", [
    {"requeue_on_preemption": False}, {"requeued_as": "b1-r1"}, {"cancel": True}, {"deleting": True}])
def test_no_copy_when_the_spec_says_no_one_exists_or_the_job_is_cancelled_or_deleted(change: dict[str, Any]) -> None:
    job = a_job().named("b1").finished(JobPhase.PREEMPTED)
    actions = plan_lifecycle([replace(job, **change)], [], NOW, TIMING)
    assert not any(isinstance(a, RequeuePreempted) for a in actions)


def test_a_preempted_job_is_requeued_before_its_ttl_can_delete_it() -> None:
    job = a_job().named("b1").with_ttl(0).finished(JobPhase.PREEMPTED, seconds_ago=3600)
    kinds = [type(a) for a in plan_lifecycle([job], [], NOW, TIMING)]
    assert RequeuePreempted in kinds and DeleteJob not in kinds


@pytest.mark.parametrize(("name", "taken", "expected"), [
    ("pick", False, "pick-r1"), ("pick-r1", False, "pick-r2"), ("pick-r9", False, "pick-r10"),
    ("pick-r0", False, "pick-r0-r1"), ("pick", True, "pick-r1-uid-abcd"), ("x" * 253, False, "x" * 250 + "-r1"),
])
def test_requeue_names(name: str, taken: bool, expected: str) -> None:
    assert requeue_name(name, "uid-abcdef", taken) == expected


def test_the_copy_drops_per_object_annotations_and_keeps_the_tenants() -> None:
    preempted = {"metadata": {"name": "b1", "namespace": "t", "uid": "u-1", "annotations": {
        "team/owner": "ana", "kubectl.kubernetes.io/last-applied-configuration": "{}",
        "armnet.io/stopped-by": "bob", "armnet.io/follower-timeout-seconds": "30"}},
        "spec": {"image": "i", "embodiment": "so101", "cancel": True}}
    body = requeue_body(preempted, "b1-r1", ago(600))
    assert body["metadata"]["annotations"] == {
        "team/owner": "ana", PREEMPTED_FROM_ANNOTATION: "u-1", QUEUED_SINCE_ANNOTATION: kube_time(ago(600))}
    assert body["spec"]["cancel"] is False and preempted["spec"]["cancel"] is True


def test_queued_since_only_moves_a_copy_earlier_and_only_with_its_origin() -> None:
    def created(annotations: dict[str, str]) -> Any:
        return parse_job({"metadata": {"name": "j", "namespace": "t", "creationTimestamp": kube_time(NOW),
                                       "annotations": annotations},
                          "spec": {"image": "i", "embodiment": "so101"}}).created
    earlier, later = kube_time(NOW - timedelta(hours=1)), kube_time(NOW + timedelta(hours=1))
    assert created({PREEMPTED_FROM_ANNOTATION: "u", QUEUED_SINCE_ANNOTATION: earlier}) == NOW - timedelta(hours=1)
    assert created({PREEMPTED_FROM_ANNOTATION: "u", QUEUED_SINCE_ANNOTATION: later}) == NOW
    assert created({QUEUED_SINCE_ANNOTATION: earlier}) == NOW
    assert created({PREEMPTED_FROM_ANNOTATION: "u", QUEUED_SINCE_ANNOTATION: "yesterday"}) == NOW


def test_a_higher_priority_of_the_same_tenant_preempts_a_lower_one_where_its_quota_allows() -> None:
    world, memory = World(), Memory()
    world.add_cell("c1", "so101", None)
    world.quotas["a"] = quota_body("a", "t", 1)
    world.quotas["a"]["spec"]["preemption"] = {"withinQuota": "LowerPriority"}
    world.submit("low", "so101", None, 1)
    run(world, memory)
    agent_runs(world, "t/low")
    world.tick(5)
    world.submit("urgent", "so101", None, 9)
    outcome = run(world, memory)
    assert world.jobs["t/urgent"]["status"]["queuedReason"] == "QuotaExhausted"
    assert outcome.preempted == {"priority": 1}
    request = world.jobs["t/low"]["status"]["preemption"]
    assert request["forJob"] == "t/urgent" and "priority 9, above this job's 1" in request["message"]

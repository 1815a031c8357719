"""The reconcile pass with CellQuotas: a tenant out of quota waits with QuotaExhausted, others bind,
and each quota's status (usage included) is written and read back after a restart."""

from __future__ import annotations

from datetime import timedelta
from typing import Any

from armnet_operator.model import Timing
from armnet_operator.quota_parsing import read_quota
from armnet_operator.reconcile import Limits, Memory, Outcome, reconcile_once

from tests.unit.operator.operator_world import World

TIMING = Timing(heartbeat_timeout=timedelta(seconds=30), claim_grace=timedelta(seconds=10),
                lost_grace=timedelta(seconds=60), cancel_force_after=timedelta(seconds=60),
                default_ttl=None)
LIMITS = Limits(quota_refresh=timedelta(seconds=30))


def quota_body(name: str, namespace: str, nominal: int, **status: Any) -> dict[str, Any]:
    return {"metadata": {"name": name, "resourceVersion": "1"},
            "spec": {"namespace": namespace, "embodiment": "so101", "nominalCells": nominal},
            "status": status}


def a_world() -> World:
    world = World()
    for name in ("c1", "c2"):
        world.add_cell(name, "so101", None)
        world.heartbeat(name)
    world.submit("a1", "so101", None, 0)
    world.tick(1)
    world.submit("a2", "so101", None, 0)
    world.tick(1)
    world.submit("b1", "so101", None, 0)
    world.jobs["t2/b1"] = world.jobs.pop("t/b1")
    world.jobs["t2/b1"]["metadata"]["namespace"] = "t2"
    return world


def run(world: World, memory: Memory, quotas: list[dict[str, Any]]) -> Outcome:
    for body in quotas:
        world.quotas.setdefault(body["metadata"]["name"], body)
    for cell in world.cells:
        world.heartbeat(cell)
    objects = [read_quota(b) for b in world.quotas.values()]
    jobs, cells = world.snapshot()
    return reconcile_once(jobs, cells, world.now, TIMING, world, memory, LIMITS, objects)


def test_a_tenant_at_its_quota_waits_with_quota_exhausted_and_the_other_tenant_binds() -> None:
    world, memory = a_world(), Memory()
    run(world, memory, [quota_body("a", "t", 1), quota_body("b", "t2", 1)])
    status = {k: j["status"] for k, j in world.jobs.items()}
    assert status["t/a1"]["phase"] == "dispatched"
    assert status["t2/b1"]["phase"] == "dispatched"
    assert status["t/a2"]["queuedReason"] == "QuotaExhausted"
    queued = next(c for c in status["t/a2"]["conditions"] if c["type"] == "Queued")
    assert "CellQuota 'a'" in queued["message"]
    assert world.quotas["a"]["status"]["cellsInUse"] == 1
    assert world.quotas["a"]["status"]["waitingJobs"] == 1


def test_usage_is_written_and_read_back_from_status_after_a_restart() -> None:
    world = a_world()
    run(world, Memory(), [quota_body("a", "t", 1)])
    world.tick(60)
    run(world, Memory(), [])  # a restarted operator: nothing in memory, usage from status
    first = world.quotas["a"]["status"]["usage"]["decayedCellSeconds"]
    assert 59 < first < 61
    world.tick(60)
    run(world, Memory(), [])
    assert 119 < world.quotas["a"]["status"]["usage"]["decayedCellSeconds"] < 121


def test_a_duplicate_quota_is_ignored_and_says_why_in_its_status() -> None:
    world = a_world()
    run(world, Memory(), [quota_body("a", "t", 1), quota_body("z", "t", 5)])
    assert "ignored" in world.quotas["z"]["status"]["message"]
    assert world.quotas["a"]["status"]["message"] == ""
    assert world.jobs["t/a2"]["status"]["queuedReason"] == "QuotaExhausted"
    assert ("z", "QuotaIgnored") in world.events and ("a", "QuotaIgnored") not in world.events


def test_an_ignored_quota_gets_one_warning_event_per_problem_and_is_counted() -> None:
    world, memory = a_world(), Memory()
    bad = {"metadata": {"name": "bad", "uid": "u-bad"},
           "spec": {"namespace": "t", "embodiment": "so101", "nominalCells": -3}}
    outcome = run(world, memory, [bad])
    run(world, memory, [bad])  # the same problem: no second Event
    assert world.events.count(("bad", "QuotaIgnored")) == 1
    assert outcome.quotas_ignored == 1
    world.quotas["bad"]["spec"] = {**bad["spec"], "nominalCells": 1, "weight": 0}
    run(world, memory, [])  # another problem: another Event
    assert world.events.count(("bad", "QuotaIgnored")) == 2


def test_a_malformed_quota_never_stops_the_pass() -> None:
    world = a_world()
    bad = {"metadata": {"name": "bad"}, "spec": {"namespace": "t", "embodiment": "so101", "nominalCells": -3}}
    run(world, Memory(), [bad])
    assert "nominalCells" in world.quotas["bad"]["status"]["message"]
    phases = sorted(j["status"].get("phase") for j in world.jobs.values())
    assert phases == ["dispatched", "dispatched", "queued"]  # the ignored quota rations nothing

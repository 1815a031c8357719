"""Pre-flight on a simulated twin, as the operator decides and writes it.

A job with ``spec.preflight`` first runs as a second RobotJob, its pre-flight, bound only
to a pre-flight Cell of its embodiment; the job waits (``PreflightRunning``) and binds a
real cell only once the pre-flight passed. A failed pre-flight fails the job without it
ever binding a real cell. No ordinary job ever binds a pre-flight cell.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import pytest
from armnet_core import api, resources
from armnet_core.api import PREFLIGHT_FOR_ANNOTATION, PreflightPhase
from armnet_operator.lifecycle import CancelPreflight, StartPreflight, plan_lifecycle
from armnet_operator.model import JobPhase, QueuedReason
from armnet_operator.parsing import parse_cell, parse_job
from armnet_operator.preflight import device_calls_of, judge, preflight_body, preflight_name
from armnet_operator.quota_parsing import read_quota
from armnet_operator.reconcile import Memory, Outcome, reconcile_once
from armnet_operator.requeue import requeue_body
from armnet_operator.scheduling import plan_bindings
from operator_builders import NOW, SO101, TIMING, a_cell, a_job, a_quota, ago

from tests.unit.architecture.test_api_models import at, schema, wire_names
from tests.unit.operator.operator_world import World
from tests.unit.operator.test_fairshare_wiring import LIMITS, quota_body

pytestmark = pytest.mark.unit

HEARTBEAT = TIMING.heartbeat_timeout


# -- the verdict ---------------------------------------------------------------------------------


@pytest.mark.parametrize(("phase", "error", "traceback", "passed", "said"), [
    (JobPhase.SUCCEEDED, None, None, True, "succeeded on pre-flight cell twin-1"),
    (JobPhase.TIMEOUT, None, None, True, "ran the pre-flight's 30 s without failing"),
    (JobPhase.FAILED, "safety violation (connector record): shoulder_pan", None, False,
     "failed on pre-flight cell twin-1: safety violation (connector record): shoulder_pan"),
    (JobPhase.FAILED, None, "Traceback (most recent call last):\n  File x\nValueError: no cube\n", False,
     "failed on pre-flight cell twin-1: ValueError: no cube"),
    (JobPhase.FAILED, None, None, False, "failed on pre-flight cell twin-1: it failed without an error message"),
    (JobPhase.CANCELLED, None, None, False, "was cancelled"),
    (JobPhase.PREEMPTED, None, None, False, "was stopped (preempted)"),
])
def test_the_verdict_on_a_finished_preflight(phase: JobPhase, error: str | None, traceback: str | None,
                                             passed: bool, said: str) -> None:
    run = a_job().named("pick-preflight").with_timeout(30).finished(phase, cell="twin-1")
    verdict = judge(run, "pick-preflight", error, traceback)
    assert verdict is not None
    assert verdict.passed is passed
    assert verdict.phase is (PreflightPhase.PASSED if passed else PreflightPhase.FAILED)
    assert said in verdict.message and "pick-preflight" in verdict.message


@pytest.mark.parametrize(("calls", "passed", "said"), [
    (0, False, "without reaching the cell (no call to its bus or cameras), which proves nothing: "
               "give spec.preflight.seconds more time"),
    (412, True, "ran the pre-flight's 30 s without failing on pre-flight cell twin-1, 412 call(s) to the twin's devices"),
    (None, True, "ran the pre-flight's 30 s without failing on pre-flight cell twin-1"),
])
def test_a_preflight_that_ran_its_time_passes_only_if_it_reached_the_twins_devices(
        calls: int | None, passed: bool, said: str) -> None:
    run = a_job().named("pick-preflight").with_timeout(30).finished(JobPhase.TIMEOUT, cell="twin-1")
    verdict = judge(run, "pick-preflight", device_calls=calls)
    assert verdict is not None and verdict.passed is passed
    assert said in verdict.message, verdict.message


def test_a_succeeded_preflight_passes_whatever_it_called() -> None:
    run = a_job().named("pick-preflight").finished(JobPhase.SUCCEEDED, cell="twin-1")
    verdict = judge(run, "pick-preflight", device_calls=0)
    assert verdict is not None and verdict.passed


@pytest.mark.parametrize(("result", "calls"), [
    ({"safety": {"deviceCalls": 7}}, 7),
    ({"safety": {"deviceCalls": 0}}, 0),
    ({}, None),
    ({"safety": None}, None),
    ({"safety": {"deviceCalls": "7"}}, None),
    ({"safety": {"deviceCalls": True}}, None),
    ({"safety": {"deviceCalls": -1}}, None),
    ({"safety": ["deviceCalls"]}, None),
])
def test_the_device_calls_are_read_from_the_result_only_when_they_are_a_count(
        result: dict[str, object], calls: int | None) -> None:
    assert device_calls_of(result) == calls


@pytest.mark.parametrize("phase", [None, JobPhase.QUEUED, JobPhase.DISPATCHED, JobPhase.RUNNING])
def test_no_verdict_while_the_preflight_has_not_ended(phase: JobPhase | None) -> None:
    assert judge(replace(a_job().new(), phase=phase), "pick-preflight") is None


def test_a_preflight_that_is_gone_fails() -> None:
    verdict = judge(None, "pick-preflight")
    assert verdict is not None and not verdict.passed and "no longer exists" in verdict.message


# -- the pre-flight's body -----------------------------------------------------------------------


def test_the_preflight_copies_the_job_with_no_preflight_of_its_own_its_bounded_time_and_no_requeue() -> None:
    job = {"metadata": {"name": "pick", "namespace": "t", "uid": "u-1", "labels": {"team": "vision"},
                        "annotations": {"team/owner": "ana", "kubectl.kubernetes.io/last-applied-configuration": "{}",
                                        "armnet.io/follower-timeout-seconds": "30"}},
           "spec": {"image": "i", "embodiment": SO101, "task": "pick", "args": {"n": 3}, "secrets": {"T": "s"},
                    "timeoutSeconds": 600, "cancel": True, "preflight": {"seconds": 20}}}
    body = preflight_body(job, "pick-preflight")
    spec = body["spec"]
    assert "preflight" not in spec and spec["cancel"] is False and spec["requeueOnPreemption"] is False
    assert spec["timeoutSeconds"] == 20
    assert (spec["args"], spec["secrets"], spec["task"], spec["image"]) == ({"n": 3}, {"T": "s"}, "pick", "i")
    assert body["metadata"]["labels"] == {"team": "vision"}
    assert body["metadata"]["annotations"] == {"team/owner": "ana", PREFLIGHT_FOR_ANNOTATION: "u-1"}
    assert body["metadata"]["ownerReferences"][0]["uid"] == "u-1"
    assert job["spec"]["preflight"] == {"seconds": 20}  # the job's own body is left as it was


def test_the_preflight_never_runs_longer_than_the_job_would() -> None:
    job = {"metadata": {"name": "pick", "namespace": "t", "uid": "u"},
           "spec": {"image": "i", "embodiment": SO101, "timeoutSeconds": 5, "preflight": {"seconds": 20}}}
    assert preflight_body(job, "pick-preflight")["spec"]["timeoutSeconds"] == 5


@pytest.mark.parametrize(("name", "taken", "expected"), [
    ("pick", False, "pick-preflight"), ("pick", True, "pick-preflight-uid-abcd"),
    ("x" * 253, False, "x" * 243 + "-preflight"),
])
def test_preflight_names(name: str, taken: bool, expected: str) -> None:
    assert preflight_name(name, "uid-abcdef", taken) == expected


def test_a_preempted_jobs_copy_runs_without_a_second_preflight() -> None:
    job = {"metadata": {"name": "pick", "namespace": "t", "uid": "u"},
           "spec": {"image": "i", "embodiment": SO101, "preflight": {"seconds": 20}}}
    assert "preflight" not in requeue_body(job, "pick-r1", NOW)["spec"]


# -- the scheduler: twins and real cells are disjoint pools ------------------------------------------


def test_an_ordinary_job_is_never_bound_to_a_preflight_cell() -> None:
    job = a_job().queued()
    twin = a_cell().named("twin").as_preflight_twin().ready()
    plan = plan_bindings([job], [twin], NOW, HEARTBEAT)
    assert plan.bindings == ()
    assert plan.queued[job.key].reason is QueuedReason.NO_CELL_FOR_EMBODIMENT


def test_a_preflight_is_never_bound_to_an_ordinary_cell() -> None:
    owner = a_job().named("pick").with_preflight().queued()
    run = a_job().preflight_of(owner).new()
    plan = plan_bindings([run], [a_cell().named("real").ready()], NOW, HEARTBEAT)
    assert plan.bindings == ()
    entry = plan.queued[run.key]
    assert entry.reason is QueuedReason.NO_CELL_FOR_EMBODIMENT and "no pre-flight Cell" in entry.message


def test_a_preflight_takes_a_twin_of_its_embodiment_whatever_its_task() -> None:
    owner = a_job().named("pick").with_task("pick-cube").with_preflight().queued()
    run = a_job().preflight_of(owner).with_task("pick-cube").new()
    cells = [a_cell().named("real").with_task("pick-cube").ready(),
             a_cell().named("twin-other").with_embodiment("other/arm").as_preflight_twin().ready(),
             a_cell().named("twin").with_task("anything").as_preflight_twin().ready()]
    plan = plan_bindings([run], cells, NOW, HEARTBEAT)
    assert [(b.job.key, b.cell.name) for b in plan.bindings] == [(run.key, "twin")]


def test_a_job_waiting_for_its_preflight_is_never_bound_and_counts_behind_every_other_job() -> None:
    owner = replace(a_job().named("pick").with_preflight().submitted_ago(500).queued(),
                    preflight_phase=PreflightPhase.RUNNING, preflight_job="pick-preflight")
    busy = a_job().named("holder").running_on("real")
    later = a_job().named("later").submitted_ago(10).queued()
    plan = plan_bindings([owner, busy, later], [a_cell().named("real").claimed_by(busy).build()], NOW, HEARTBEAT)
    assert plan.bindings == ()
    assert plan.queued[later.key].position == 1
    entry = plan.queued[owner.key]
    assert entry.reason is QueuedReason.PREFLIGHT_RUNNING and entry.position == 2
    assert "pick-preflight" in entry.message and entry.latest_start is None


def test_a_job_whose_preflight_passed_binds_in_its_original_place() -> None:
    first = replace(a_job().named("first").with_preflight().submitted_ago(500).queued(),
                    preflight_phase=PreflightPhase.PASSED, preflight_job="first-preflight")
    second = a_job().named("second").submitted_ago(100).queued()
    plan = plan_bindings([second, first], [a_cell().named("real").ready()], NOW, HEARTBEAT)
    assert [b.job.key for b in plan.bindings] == [first.key]


def test_a_preflight_is_rationed_by_no_cellquota_and_preempted_by_none() -> None:
    owner = a_job().named("pick").with_preflight().queued()
    run = a_job().preflight_of(owner).new()
    quota = a_quota("tenant-a").named("a").nominal(0).build()
    plan = plan_bindings([run], [a_cell().named("twin").as_preflight_twin().ready()], NOW, HEARTBEAT, [quota])
    assert [b.cell.name for b in plan.bindings] == ["twin"]
    running = replace(run, phase=JobPhase.RUNNING, cell_name="twin", bound_at=ago(5))
    waiting = a_job().named("urgent").with_priority(9).queued()
    lower = a_quota("tenant-a").named("a").nominal(1).preempting_lower_priorities().build()
    twin = a_cell().named("twin").as_preflight_twin().claimed_by(running).build()
    assert plan_bindings([running, waiting], [twin], NOW, HEARTBEAT, [lower]).reclaims == ()


def test_a_pre_flight_cell_that_is_not_simulated_is_never_bound() -> None:
    cell = parse_cell({"metadata": {"name": "c"}, "spec": {"embodiment": SO101, "nodeName": "n", "preflight": True}})
    assert cell.preflight and "must be simulated" in (cell.spec_problem or "")


# -- the lifecycle ---------------------------------------------------------------------------------


def test_a_preflight_whose_job_is_cancelled_deleted_gone_or_over_is_cancelled() -> None:
    owner = a_job().named("pick").with_preflight().queued()
    run = replace(a_job().preflight_of(owner).running_on("twin"))
    assert CancelPreflight(run, recheck=True) in plan_lifecycle([run], [], NOW, TIMING)  # not in view: read first
    for gone in ([replace(owner, cancel=True)], [replace(owner, deleting=True)],
                 [replace(owner, phase=JobPhase.FAILED, finished_at=ago(1))]):
        assert CancelPreflight(run) in plan_lifecycle([run, *gone], [], NOW, TIMING)
    assert not any(isinstance(a, CancelPreflight) for a in plan_lifecycle([run, owner], [], NOW, TIMING))
    assert not any(isinstance(a, CancelPreflight)
                   for a in plan_lifecycle([replace(run, cancel=True)], [], NOW, TIMING))


def test_only_a_waiting_job_starts_a_preflight_and_a_preflight_never_starts_its_own() -> None:
    owner = a_job().named("pick").with_preflight().new()
    assert StartPreflight(owner) in plan_lifecycle([owner], [], NOW, TIMING)
    for never in (replace(owner, cancel=True), replace(owner, preflight_for="uid-x"),
                  replace(owner, preflight_phase=PreflightPhase.PASSED, preflight_job="pick-preflight")):
        assert not any(isinstance(a, StartPreflight) for a in plan_lifecycle([never], [], NOW, TIMING))


# -- the writes, on the in-memory API server --------------------------------------------------------


def twin_world(**spec: Any) -> World:
    """One real cell, one pre-flight twin, and job ``pick`` asking for a 30 s pre-flight."""
    world = World()
    world.add_cell("real", "so101", None)
    world.add_cell("twin", "so101", None, simulated=True, preflight=True)
    world.submit("pick", "so101", None, 0, preflight={"seconds": 30}, timeoutSeconds=300, **spec)
    return world


def run(world: World, memory: Memory) -> Outcome:
    for cell in world.cells:
        world.heartbeat(cell)
    jobs, cells = world.snapshot()
    quotas = [read_quota(b) for b in world.quotas.values()]
    return reconcile_once(jobs, cells, world.now, TIMING, world, memory, LIMITS, quotas)


def status(world: World, key: str) -> dict[str, Any]:
    return dict(world.jobs[key].get("status") or {})


def test_a_job_with_a_preflight_gets_it_created_once_and_waits_while_it_runs_on_the_twin() -> None:
    world, memory = twin_world(), Memory()
    run(world, memory)
    parent = status(world, "t/pick")
    assert parent["phase"] == "queued" and parent["queuedReason"] == "PreflightRunning"
    assert parent["preflight"]["phase"] == "Running" and parent["preflight"]["job"] == "pick-preflight"
    assert "cellName" not in parent
    child = world.jobs["t/pick-preflight"]
    assert child["metadata"]["annotations"][PREFLIGHT_FOR_ANNOTATION] == world.jobs["t/pick"]["metadata"]["uid"]
    assert child["spec"]["timeoutSeconds"] == 30 and "preflight" not in child["spec"]
    assert status(world, "t/pick-preflight")["cellName"] == "twin"  # bound in the same pass
    assert ("t/pick", "PreflightStarted") in world.events
    world.agent_set_phase("t/pick-preflight", "running")
    world.tick(5)
    run(world, memory)
    assert sorted(world.jobs) == ["t/pick", "t/pick-preflight"]
    assert status(world, "t/pick")["queuedReason"] == "PreflightRunning"
    assert world.cells["real"]["status"].get("currentJob") is None


def test_a_job_whose_preflight_succeeded_binds_to_an_ordinary_cell() -> None:
    world, memory = twin_world(), Memory()
    run(world, memory)
    world.agent_set_phase("t/pick-preflight", "succeeded")
    world.tick(5)
    outcome = run(world, memory)
    parent = status(world, "t/pick")
    assert parent["preflight"]["phase"] == "Passed" and "succeeded" in parent["preflight"]["message"]
    assert parent["phase"] == "dispatched" and parent["cellName"] == "real"
    assert outcome.preflights == {"passed": 1}
    assert ("t/pick", "PreflightPassed") in world.events


def preflight_timed_out(device_calls: int) -> dict[str, Any]:
    """The job's status after its pre-flight ran its whole time with ``device_calls`` on the twin."""
    world, memory = twin_world(), Memory()
    run(world, memory)
    world.jobs["t/pick-preflight"]["status"]["result"] = {"safety": {"policy": "clamp", "deviceCalls": device_calls}}
    world.agent_set_phase("t/pick-preflight", "timeout")
    world.tick(31)
    run(world, memory)
    return status(world, "t/pick")


def test_a_preflight_that_ran_its_whole_time_on_the_twins_devices_passes() -> None:
    parent = preflight_timed_out(900)
    assert parent["preflight"]["phase"] == "Passed" and parent["cellName"] == "real"


def test_a_preflight_that_ran_its_whole_time_without_reaching_the_twin_fails_its_job() -> None:
    parent = preflight_timed_out(0)
    assert parent["phase"] == "failed" and "cellName" not in parent
    assert "without reaching the cell" in parent["result"]["error"]
    assert "spec.preflight.seconds" in parent["result"]["error"]


def test_a_job_whose_preflight_failed_fails_and_never_binds_a_real_cell() -> None:
    world, memory = twin_world(), Memory()
    run(world, memory)
    world.jobs["t/pick-preflight"]["status"]["result"] = {"error": "safety violation (connector record): shoulder_pan"}
    world.agent_set_phase("t/pick-preflight", "failed")
    world.tick(2)
    outcome = run(world, memory)
    parent = status(world, "t/pick")
    assert parent["phase"] == "failed" and "cellName" not in parent
    assert parent["preflight"]["phase"] == "Failed"
    assert parent["result"]["error"].startswith("pre-flight failed: ")
    assert "pick-preflight" in parent["result"]["error"] and "shoulder_pan" in parent["result"]["error"]
    queued = next(c for c in parent["conditions"] if c["type"] == "Queued")
    assert queued["status"] == "False" and queued["reason"] == "PreflightFailed"
    assert outcome.preflights == {"failed": 1}
    assert ("t/pick", "PreflightFailed") in world.events
    world.tick(5)
    run(world, memory)
    assert world.cells["real"]["status"].get("currentJob") is None


def test_cancelling_a_job_during_its_preflight_cancels_both() -> None:
    world, memory = twin_world(), Memory()
    run(world, memory)
    world.agent_set_phase("t/pick-preflight", "running")
    world.user_patch_job("t/pick", {"cancel": True})
    run(world, memory)
    assert status(world, "t/pick")["phase"] == "cancelled"
    assert world.jobs["t/pick-preflight"]["spec"]["cancel"] is True  # the agent stops it on the twin


def test_verdicts_are_counted_in_armnet_preflights_total() -> None:
    from armnet_operator.metrics import Metrics

    metrics = Metrics()
    sample = metrics.registry.get_sample_value
    assert sample("armnet_preflights_total", {"verdict": "failed"}) == 0  # exported before the first one
    world, memory = twin_world(), Memory()
    run(world, memory)
    world.agent_set_phase("t/pick-preflight", "failed")
    jobs, cells = world.snapshot()
    metrics.observe(run(world, memory), jobs, cells, world.now)
    assert sample("armnet_preflights_total", {"verdict": "failed"}) == 1
    assert sample("armnet_preflights_total", {"verdict": "passed"}) == 0


def test_a_preflight_whose_job_is_not_in_view_yet_is_left_running_and_one_whose_job_is_gone_is_cancelled() -> None:
    world, memory = twin_world(), Memory()
    run(world, memory)
    world.agent_set_phase("t/pick-preflight", "running")
    jobs, cells = world.snapshot()
    lagging = [j for j in jobs if j.key != "t/pick"]  # a watch still listing: the job is not in view yet
    reconcile_once(lagging, cells, world.now, TIMING, world, memory, LIMITS)
    assert world.jobs["t/pick-preflight"]["spec"].get("cancel") is not True
    del world.jobs["t/pick"]  # deleted and gone (its finalizer removed)
    run(world, memory)
    assert world.jobs["t/pick-preflight"]["spec"]["cancel"] is True


def test_a_preflight_created_before_a_crash_is_found_not_created_twice() -> None:
    world = twin_world()
    world.create_job(preflight_body(world.read_job("t", "pick"), "pick-preflight"))  # the crash came before the status
    run(world, Memory())
    assert status(world, "t/pick")["preflight"]["job"] == "pick-preflight"
    assert sorted(world.jobs) == ["t/pick", "t/pick-preflight"]


def test_a_tenants_own_job_with_the_preflights_name_is_left_alone() -> None:
    world = twin_world()
    world.submit("pick-preflight", "so101", None, 0)
    run(world, Memory())
    name = status(world, "t/pick")["preflight"]["job"]
    assert name == "pick-preflight-uid-pick"
    assert PREFLIGHT_FOR_ANNOTATION not in (world.jobs["t/pick-preflight"]["metadata"].get("annotations") or {})


def test_a_preflight_is_run_even_when_the_tenants_quota_has_no_cell_left() -> None:
    world, memory = twin_world(), Memory()
    world.quotas["a"] = quota_body("a", "t", 0)
    run(world, memory)
    assert status(world, "t/pick-preflight")["cellName"] == "twin"


# -- the API's models agree with the CRD ----------------------------------------------------------


@pytest.mark.parametrize(("path", "model"), [
    (("spec", "preflight"), resources.PreflightSpec), (("status", "preflight"), resources.PreflightStatus)])
def test_the_preflight_models_are_the_crds(path: tuple[str, ...], model: Any) -> None:
    node = at(schema(api.ROBOTJOBS), *path)
    assert set(wire_names(model)) == set(node["properties"])
    required = {wire for wire, name in wire_names(model).items() if model.model_fields[name].is_required()}
    assert required == set(node.get("required", []))
    if "phase" in node["properties"]:
        assert tuple(node["properties"]["phase"]["enum"]) == tuple(PreflightPhase)


def test_a_parsed_job_carries_its_preflight() -> None:
    job = parse_job({"metadata": {"name": "pick", "namespace": "t", "annotations": {PREFLIGHT_FOR_ANNOTATION: "u"}},
                     "spec": {"image": "i", "embodiment": SO101, "preflight": {"seconds": 7}},
                     "status": {"preflight": {"phase": "Running", "job": "pick-preflight"}}})
    assert (job.preflight_seconds, job.preflight_phase, job.preflight_job, job.preflight_for) == (
        7, PreflightPhase.RUNNING, "pick-preflight", "u")


def test_jobs_with_preflights_all_end_when_agents_keep_working() -> None:
    """Liveness: one twin and one real cell drain a queue of jobs with and without pre-flights."""
    world, memory = World(), Memory()
    world.add_cell("real", "so101", None)
    world.add_cell("twin", "so101", None, simulated=True, preflight=True)
    for i in range(6):
        extra = {"preflight": {"seconds": 30}} if i % 2 == 0 else {}
        world.submit(f"j{i}", "so101", None, 0, **extra)
    for _ in range(120):
        run(world, memory)
        for name in ("real", "twin"):
            claim = world.cells[name]["status"].get("currentJob")
            body = world.jobs.get(claim or "")
            if body and body["status"].get("phase") == "dispatched":
                world.agent_set_phase(claim, "running")
            elif body and body["status"].get("phase") == "running":
                world.agent_set_phase(claim, "succeeded")
        world.tick(1)
    phases = {key: body["status"].get("phase") for key, body in world.jobs.items()}
    assert phases == {**{f"t/j{i}": "succeeded" for i in range(6)},
                      **{f"t/j{i}-preflight": "succeeded" for i in range(0, 6, 2)}}
    assert {world.jobs[f"t/j{i}"]["status"]["cellName"] for i in range(6)} == {"real"}

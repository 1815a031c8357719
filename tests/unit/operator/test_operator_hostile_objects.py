"""Hostile RobotJobs and Cells meet the pure core: no overflow, no crash, no silent queue.

Each rule is one table or one test: bad TTLs, unreadable status fields, args
beyond the limits, jobs that claim to run without the cell's claim, and cells
that fail a check.
"""

from __future__ import annotations

from dataclasses import replace

import pytest
from armnet_core.api import RELEASE_CELL_FINALIZER
from armnet_operator.args import MAX_ARGS_BYTES, MAX_ARGS_DEPTH, args_problem
from armnet_operator.cell_checks import MAX_SAFETY_LIMIT, check_cell, check_cells
from armnet_operator.health import derive_cell_phase
from armnet_operator.lifecycle import (
    DeleteJob,
    FinishJob,
    RepairStatus,
    SetCellPhase,
    plan_lifecycle,
)
from armnet_operator.model import Arm, CellPhase, JobPhase
from armnet_operator.parsing import parse_cell, parse_job
from armnet_operator.patches import repair_status, set_cell_phase
from armnet_operator.scheduling import plan_bindings
from operator_builders import NOW, TIMING, a_cell, a_job, ago

pytestmark = pytest.mark.unit


def of_type(actions, kind):
    return [a for a in actions if isinstance(a, kind)]


def deep(levels: int) -> dict:
    value: dict = {"leaf": 1}
    for _ in range(levels - 1):
        value = {"a": value}
    return value


def job_body(**status: object) -> dict:
    return {
        "metadata": {"name": "j", "namespace": "t", "uid": "u", "resourceVersion": "7",
                     "creationTimestamp": "2026-01-01T12:00:00Z"},
        "spec": {"embodiment": "lerobot/so-101", "args": {}},
        "status": status,
    }


# ---------------------------------------------------------------- numbers
@pytest.mark.parametrize("ttl", [9223372036854775807, 10**15, 2**63 - 1, -5])
def test_an_extreme_ttl_neither_overflows_nor_deletes_a_job_early(ttl: int) -> None:
    job = a_job().with_ttl(ttl).finished(seconds_ago=10)
    actions = plan_lifecycle([job], [], NOW, TIMING)
    assert of_type(actions, DeleteJob) == ([DeleteJob(job)] if ttl < 0 else [])


def test_a_huge_ttl_is_clamped_to_a_year_not_forever() -> None:
    job = a_job().with_ttl(9223372036854775807).finished(seconds_ago=400 * 24 * 3600)
    assert of_type(plan_lifecycle([job], [], NOW, TIMING), DeleteJob) == [DeleteJob(job)]


def test_an_extreme_priority_still_sorts() -> None:
    jobs = [a_job().with_priority(2**70).new(), a_job().with_priority(-(2**70)).new()]
    plan = plan_bindings(jobs, [a_cell().ready()], NOW, TIMING.heartbeat_timeout)
    assert plan.bindings[0].job == jobs[0]


# ---------------------------------------------------------------- status repaired
@pytest.mark.parametrize(("status", "field"), [
    ({"finishedAt": "not a time"}, "status.finishedAt"),
    ({"queuePosition": "first"}, "status.queuePosition"),
    ({"phase": "exploded"}, "status.phase"),
    ({"conditions": [{"type": "Bound", "status": "True", "lastTransitionTime": "yesterday"}]},
     "status.conditions[0]"),
])
def test_an_unreadable_status_field_is_named_and_the_job_stays_in_view(status: dict, field: str) -> None:
    job = parse_job(job_body(**status))
    assert job.key == "t/j"
    assert job.status_defects == (field,)


def test_an_unreadable_status_field_is_repaired_by_clearing_it() -> None:
    job = parse_job(job_body(phase="queued", finishedAt="not a time"))
    [repair] = of_type(plan_lifecycle([job], [], NOW, TIMING), RepairStatus)
    body = repair_status(repair.job).body
    assert body["status"] == {"finishedAt": None}
    assert body["metadata"]["resourceVersion"] == "7"


def test_an_unreadable_condition_is_dropped_and_the_readable_ones_kept() -> None:
    job = parse_job(job_body(conditions=[
        {"type": "Queued", "status": "True", "lastTransitionTime": "2026-01-01T12:00:00Z"},
        {"type": "Bound", "status": "True", "lastTransitionTime": "yesterday"},
    ]))
    assert [c["type"] for c in repair_status(job).body["status"]["conditions"]] == ["Queued"]


def test_a_timestamp_without_a_zone_is_read_as_utc_so_it_compares_with_now() -> None:
    job = parse_job(job_body(phase="succeeded", finishedAt="2026-01-01T11:00:00"))
    assert job.finished_at is not None and job.finished_at.tzinfo is not None
    plan_lifecycle([job], [], NOW, TIMING)  # no TypeError comparing naive and aware


def test_a_deleting_job_with_an_unreadable_status_still_loses_its_finalizer() -> None:
    body = job_body(phase="cancelled", finishedAt="garbage")
    body["metadata"].update(deletionTimestamp="2026-01-01T12:00:00Z", finalizers=[RELEASE_CELL_FINALIZER])
    actions = plan_lifecycle([parse_job(body)], [], NOW, TIMING)
    assert {type(a).__name__ for a in actions} == {"RepairStatus", "RemoveFinalizer"}


# ---------------------------------------------------------------- the claim is the one truth
def test_a_running_job_its_cell_does_not_claim_fails_with_the_reason() -> None:
    holder = a_job().running_on("c")
    intruder = a_job().running_on("c")
    cell = a_cell().named("c").claimed_by(holder).ready()
    [finish] = of_type(plan_lifecycle([holder, intruder], [cell], NOW, TIMING), FinishJob)
    assert finish.job == intruder and finish.phase is JobPhase.FAILED
    assert f"holds {holder.key}" in (finish.error or "")


def test_a_running_job_written_by_hand_without_a_bind_fails_at_once() -> None:
    forged = replace(a_job().running_on("c"), bound_at=None)
    cell = a_cell().named("c").ready()
    [finish] = of_type(plan_lifecycle([forged], [cell], NOW, TIMING), FinishJob)
    assert finish.reason == "ClaimNotHeld"


def test_a_running_job_just_bound_is_left_alone_while_the_watch_catches_up() -> None:
    job = replace(a_job().running_on("c"), bound_at=ago(1))
    cell = a_cell().named("c").ready()
    assert of_type(plan_lifecycle([job], [cell], NOW, TIMING), FinishJob) == []


# ---------------------------------------------------------------- args
@pytest.mark.parametrize(("args", "says"), [
    (deep(MAX_ARGS_DEPTH + 1), f"nested more than {MAX_ARGS_DEPTH} levels"),
    (deep(5000), f"nested more than {MAX_ARGS_DEPTH} levels"),
    ({"blob": "x" * (MAX_ARGS_BYTES + 1)}, f"larger than {MAX_ARGS_BYTES} bytes"),
    ({"many": list(range(MAX_ARGS_BYTES))}, f"larger than {MAX_ARGS_BYTES} bytes"),
    (["not", "an", "object"], "must be an object"),
])
def test_args_beyond_the_limits_say_which_limit(args: object, says: str) -> None:
    assert says in (args_problem(args) or "")


@pytest.mark.parametrize("args", [{}, deep(MAX_ARGS_DEPTH), {"blob": "x" * (MAX_ARGS_BYTES - 20)}, None])
def test_args_within_the_limits_pass(args: object) -> None:
    assert args_problem(args) is None


def test_a_job_with_args_too_deep_fails_with_the_reason_instead_of_waiting() -> None:
    body = job_body()
    body["spec"]["args"] = deep(900)
    job = parse_job(body)
    assert not job.waiting
    [finish] = of_type(plan_lifecycle([job], [], NOW, TIMING), FinishJob)
    assert (finish.phase, finish.reason) == (JobPhase.FAILED, "InvalidSpec")
    assert "spec.args is nested" in (finish.error or "")
    assert plan_bindings([job], [a_cell().ready()], NOW, TIMING.heartbeat_timeout).bindings == ()


def test_a_spec_field_of_the_wrong_type_fails_the_job_naming_the_field() -> None:
    body = job_body()
    body["spec"]["priority"] = "high"
    job = parse_job(body)
    assert job.spec_problem is not None and "spec.priority" in job.spec_problem


# ---------------------------------------------------------------- cells
ARM = Arm("robot", port="/dev/ttyACM0", robot_id="r1", calibration_dir="/var/lib/armnet/cal/r1", safety_limit=10)


@pytest.mark.parametrize(("arms", "says"), [
    ((replace(ARM, safety_limit=1e9),), "safetyLimit"),
    ((replace(ARM, safety_limit=0.0),), "safetyLimit"),
    ((replace(ARM, calibration_dir="../../etc/passwd"),), "calibrationDir"),
    ((replace(ARM, calibration_dir="/var/lib/../../etc"),), "calibrationDir"),
    ((replace(ARM, port="dev/ttyACM0"),), "port"),
    ((replace(ARM, name="arms.left"), replace(ARM, name="arms.right", robot_id="r2")), "port"),
    ((replace(ARM, name="arms.left"), replace(ARM, name="arms.right", port="/dev/ttyACM1")), "robotId"),
])
def test_a_cell_failing_a_check_says_which_field(arms: tuple[Arm, ...], says: str) -> None:
    assert says in (check_cell(replace(a_cell().ready(), arms=arms)) or "")


def test_a_sound_cell_passes() -> None:
    assert check_cell(replace(a_cell().ready(), arms=(ARM, replace(ARM, name="x", port="/dev/b", robot_id="r2")))) is None
    assert MAX_SAFETY_LIMIT >= 10


def test_two_cells_of_one_node_on_one_port_the_younger_is_invalid() -> None:
    older = replace(a_cell().named("older").ready(), node_name="h", arms=(ARM,), created=ago(100))
    younger = replace(a_cell().named("younger").ready(), node_name="h", arms=(ARM,), created=ago(10))
    elsewhere = replace(a_cell().named("elsewhere").ready(), node_name="h2", arms=(ARM,), created=ago(5))
    checked = {c.name: c.invalid for c in check_cells([younger, older, elsewhere])}
    assert checked["older"] is None and checked["elsewhere"] is None
    assert "already used by cell older on node h" in (checked["younger"] or "")


def test_an_invalid_cell_is_never_bound_and_shows_phase_invalid_with_the_reason() -> None:
    cell = replace(a_cell().ready(), invalid="spec.robot.safetyLimit 1e9 is outside (0, 45.0]")
    assert derive_cell_phase(cell, False, NOW, TIMING.heartbeat_timeout) is CellPhase.INVALID
    assert plan_bindings([a_job().new()], [cell], NOW, TIMING.heartbeat_timeout).bindings == ()
    [set_phase] = of_type(plan_lifecycle([], [cell], NOW, TIMING), SetCellPhase)
    assert set_cell_phase(set_phase.cell, set_phase.phase).body["status"] == {
        "phase": "Invalid", "message": cell.invalid}


def test_a_cell_body_with_arms_parses_each_arm() -> None:
    cell = parse_cell({"metadata": {"name": "c", "creationTimestamp": "2026-01-01T12:00:00Z"},
                       "spec": {"embodiment": "lerobot/bimanual_so101", "nodeName": "h", "arms": {
                           "left": {"port": "/dev/a", "robotId": "l", "safetyLimit": 5},
                           "right": {"port": "/dev/a", "robotId": "r"}}}})
    assert [a.name for a in cell.arms] == ["arms.left", "arms.right"]
    assert "port" in (check_cell(cell) or "")



def test_a_cell_with_an_unreadable_spec_field_stays_in_view_and_is_invalid_naming_it() -> None:
    cell = parse_cell({"metadata": {"name": "c"},
                       "spec": {"embodiment": "lerobot/so-101", "nodeName": "h", "unschedulable": "perhaps"}})
    [checked] = check_cells([cell])
    assert checked.name == "c" and "spec.unschedulable" in (checked.invalid or "")


HALF = {"left": 0.0, "top": 0.0, "width": 0.5, "height": 0.5}


@pytest.mark.parametrize(("completion", "says"), [
    ({"scorer": "region", "camera": "top", "arucoId": 7,
      "region": {"left": 0.5, "top": 0.0, "width": 0.9, "height": 0.5}}, "spec.completion"),
    ({"scorer": "crystal-ball", "camera": "top", "arucoId": 7}, "spec.completion.scorer"),
    ({"scorer": "region", "camera": "side", "arucoId": 7, "region": HALF}, "spec.completion.camera 'side'"),
    ("yes", "spec.completion"),
])
def test_a_completion_monitor_that_slipped_past_the_crd_makes_the_cell_invalid_naming_it(
        completion: object, says: str) -> None:
    """The connector would refuse to start it: the cell is Invalid (never bound, see above) until fixed."""
    cell = parse_cell({"metadata": {"name": "c"}, "spec": {
        "embodiment": "lerobot/so-101", "nodeName": "h", "cameras": {"top": {"indexOrPath": 0}},
        "completion": completion}})
    [checked] = check_cells([cell])
    assert says in (checked.invalid or ""), checked.invalid


def test_a_sound_completion_monitor_leaves_the_cell_valid() -> None:
    cell = parse_cell({"metadata": {"name": "c"}, "spec": {
        "embodiment": "lerobot/so-101", "nodeName": "h", "cameras": {"top": {"indexOrPath": 0}},
        "completion": {"scorer": "region", "camera": "top", "arucoId": 7, "region": HALF}}})
    assert cell.spec_problem is None and check_cells([cell])[0].invalid is None


def test_a_completion_nested_10000_deep_or_1_mib_long_is_an_invalid_cell_not_a_crash() -> None:
    deep: dict[str, object] = {}
    inner = deep
    for _ in range(10_000):
        inner["a"] = {}
        inner = inner["a"]  # type: ignore[assignment]
    spec = {"embodiment": "lerobot/so-101", "nodeName": "h", "cameras": {"top": {"indexOrPath": 0}}}
    nested = parse_cell({"metadata": {"name": "c"}, "spec": {**spec, "completion": deep}})
    assert "nested deeper than" in (nested.spec_problem or "")
    long = parse_cell({"metadata": {"name": "c"}, "spec": {**spec, "completion": {"scorer": "x" * (1 << 20)}}})
    assert "larger than 65536 bytes" in (long.spec_problem or "") and len(long.spec_problem or "") < 4096

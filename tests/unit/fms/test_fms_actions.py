"""What each operator action sends and writes, and when it is refused."""

from __future__ import annotations

import json

import pytest
from armnet_core.api import STOPPED_BY_ANNOTATION
from armnet_fms.actions import ActionKind, Refused, plan_action
from armnet_fms.view import build_fleet, pending_from_notice

from tests.unit.fms.fms_builders import NOW, a_cell, a_job, a_notice, a_rollout

pytestmark = pytest.mark.unit


def row(job=None, pending=None, **cell):
    jobs = [job] if job is not None else []
    return build_fleet([a_cell(**cell)], jobs, {"so101-a": pending} if pending else {}, NOW)[0]


def waiting_row():
    return row(a_job(), pending_from_notice("so101-a", a_notice(), 30, NOW - 5))


def test_confirm_reset_sends_the_pending_request_id_on_the_cells_subject() -> None:
    target = waiting_row()
    plan = plan_action(ActionKind.CONFIRM_RESET, target, "maria", NOW, request=target.reset.request_id)
    (subject, data), = plan.messages
    assert subject == "fms.so101-a.reset.confirm"
    assert json.loads(data) == {"by": "maria", "request": target.reset.request_id}
    assert plan.confirmed_request == target.reset.request_id


def test_a_confirmation_for_an_earlier_reset_is_refused() -> None:
    with pytest.raises(Refused, match="earlier reset"):
        plan_action(ActionKind.CONFIRM_RESET, waiting_row(), "maria", NOW, request="job-uid-1@an-older-wait")


def test_a_confirmation_after_the_reset_timed_out_is_refused() -> None:
    target = waiting_row()
    with pytest.raises(Refused, match="no reset is waiting"):
        plan_action(ActionKind.CONFIRM_RESET, target, "maria", NOW + 26, request=target.reset.request_id)


def test_fail_sends_an_unsuccessful_outcome_and_audits_the_rollout() -> None:
    plan = plan_action(ActionKind.FAIL, row(a_job(rollout={"index": 3, "total": 10})), "maria", NOW)
    (subject, data), = plan.messages
    assert subject == "fms.so101-a.outcome" and json.loads(data) == {"success": False, "by": "maria", "rollout": 3}
    assert plan.event.kind == "RobotJob" and plan.event.name == "eval-1"
    assert plan.event.message == "rollout 3/10 marked failure by cell operator maria"


def test_an_outcome_without_a_rollout_is_refused() -> None:
    with pytest.raises(Refused, match="no rollout"):
        plan_action(ActionKind.SUCCESS, row(a_job()), "maria", NOW)


def test_stop_cancels_the_job_naming_the_operator() -> None:
    plan = plan_action(ActionKind.STOP, row(a_job()), "maria", NOW)
    assert plan.job_patch == ("team-a", "eval-1",
                              {"metadata": {"annotations": {STOPPED_BY_ANNOTATION: "maria"}}, "spec": {"cancel": True}})
    assert plan.event.message == "stopped by cell operator maria" and plan.event.type == "Warning"


def test_stop_on_a_cell_without_a_running_job_is_refused() -> None:
    with pytest.raises(Refused, match="runs no job"):
        plan_action(ActionKind.STOP, row(a_job(phase="succeeded")), "maria", NOW)


def test_cordon_sets_unschedulable_and_audits_the_cell() -> None:
    plan = plan_action(ActionKind.CORDON, row(), "maria", NOW,
                       cell_uid="uid-so101-a")
    assert plan.cell_spec_patch == {"spec": {"unschedulable": True}}
    assert (plan.event.kind, plan.event.namespace, plan.event.uid) == ("Cell", "default", "uid-so101-a")


def test_uncordon_clears_unschedulable() -> None:
    plan = plan_action(ActionKind.UNCORDON, row(unschedulable=True), "maria", NOW)
    assert plan.cell_spec_patch == {"spec": {"unschedulable": False}}


def test_a_verdict_drawn_for_an_earlier_rollout_is_refused() -> None:
    with pytest.raises(Refused, match="for rollout 2; the job is on rollout 3"):
        plan_action(ActionKind.SUCCESS, row(a_job(rollout={"index": 3, "total": 10})), "maria", NOW, request="2")


def test_a_verdict_for_the_current_rollout_is_sent() -> None:
    plan = plan_action(ActionKind.SUCCESS, row(a_job(rollout={"index": 3, "total": 10})), "maria", NOW, request="3")
    assert [subject for subject, _ in plan.messages] == ["fms.so101-a.outcome"]


def test_a_verdict_for_a_rollout_begun_without_outcome_controls_is_refused() -> None:
    job = a_job(rollout={"index": 1, "total": 1}, rollouts=[{**a_rollout(1, 1, ended=False), "outcomeControls": False}])
    with pytest.raises(Refused, match="asks for no verdict"):
        plan_action(ActionKind.SUCCESS, row(job), "maria", NOW, request="1")


def test_a_verdict_for_a_rollout_that_has_ended_is_refused() -> None:
    job = a_job(rollout={"index": 3, "total": 10}, rollouts=[a_rollout(3, 10, ended=True)])
    with pytest.raises(Refused, match="rollout 3 of job team-a/eval-1 has ended"):
        plan_action(ActionKind.FAIL, row(job), "maria", NOW, request="3")


def judged_job(**job):  # noqa: ANN003, ANN201 - a_job's fields
    history = [a_rollout(1, 3, outcome="success", by="monitor", monitor=("success", 0.93)),
               a_rollout(2, 3, outcome="failure", by="ana", monitor=("success", 0.61)),
               a_rollout(3, 3, ended=False)]
    return a_job(rollout={"index": 3, "total": 3}, rollouts=history, **job)


def test_an_overrule_of_the_monitor_names_the_rollout_by_index_and_start_and_is_audited() -> None:
    plan = plan_action(ActionKind.OVERRULE_FAIL, row(judged_job()), "maria", NOW,
                       request="1@2027-01-15T07:58:00.000Z")
    (subject, data), = plan.messages
    assert subject == "fms.so101-a.overrule"
    assert json.loads(data) == {"success": False, "by": "maria", "rollout": 1, "startedAt": "2027-01-15T07:58:00.000Z"}
    assert plan.event.reason == "RolloutOverruled"
    assert plan.event.message == ("rollout 1/3 marked failure by cell operator maria over the monitor's success, "
                                  "score 0.93")
    # An operator's overrule can be overruled again (a slip of the finger).
    again = plan_action(ActionKind.OVERRULE_SUCCESS, row(judged_job()), "maria", NOW,
                        request="2@2027-01-15T07:58:00.000Z")
    assert json.loads(again.messages[0][1])["success"] is True


@pytest.mark.parametrize("request_, match", [
    ("3@2027-01-15T07:58:00.000Z", "no rollout the monitor judged"),  # not judged by the monitor
    ("1@2027-01-15T07:57:00.000Z", "no rollout the monitor judged"),  # another rollout of that index
    ("", "no rollout the monitor judged"),
])
def test_an_overrule_naming_no_verdict_of_the_monitor_is_refused(request_: str, match: str) -> None:
    with pytest.raises(Refused, match=match):
        plan_action(ActionKind.OVERRULE_FAIL, row(judged_job()), "maria", NOW, request=request_)


def test_an_overrule_once_the_job_ended_is_refused() -> None:
    with pytest.raises(Refused, match="runs no job now"):
        plan_action(ActionKind.OVERRULE_FAIL, row(judged_job(phase="succeeded")), "maria", NOW,
                    request="1@2027-01-15T07:58:00.000Z")

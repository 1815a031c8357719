"""The fleet rows the cell operator sees, built from Cells, their jobs and pending resets."""

from __future__ import annotations

import json

import pytest
from armnet_fms.view import build_fleet, pending_from_notice, row_json

from tests.unit.fms.fms_builders import NOW, a_cell, a_job, a_notice, a_rollout

pytestmark = pytest.mark.unit


def only_row(cells, jobs=(), pending=None, **kw):
    rows = build_fleet(cells, jobs, pending or {}, NOW, **kw)
    assert len(rows) == 1
    return rows[0]


def test_a_row_names_the_current_job_its_tenant_and_the_rollout_progress() -> None:
    row = row_json(only_row([a_cell()], [a_job(rollout={"index": 2, "total": 5}, progress="picking")]), NOW)
    assert row["job"] == {"namespace": "team-a", "name": "eval-1", "tenant": "team-a", "phase": "running",
                          "progress": "picking", "rolloutIndex": 2, "rolloutTotal": 5, "active": True,
                          "rolloutActive": True, "outcomeControls": True, "verdicts": []}


def test_a_rollout_whose_end_the_agent_recorded_is_not_active() -> None:
    job = a_job(rollout={"index": 2, "total": 2}, rollouts=[a_rollout(1), a_rollout(2, ended=True)])
    assert row_json(only_row([a_cell()], [job]), NOW)["job"]["rolloutActive"] is False


def test_a_rollout_begun_and_not_ended_is_active() -> None:
    job = a_job(rollout={"index": 2, "total": 2}, rollouts=[a_rollout(1), a_rollout(2, ended=False)])
    assert row_json(only_row([a_cell()], [job]), NOW)["job"]["rolloutActive"] is True


def test_a_rollout_begun_without_outcome_controls_asks_for_no_verdict() -> None:
    job = a_job(rollout={"index": 1, "total": 1}, rollouts=[{**a_rollout(1, ended=False), "outcomeControls": False}])
    assert row_json(only_row([a_cell()], [job]), NOW)["job"]["outcomeControls"] is False


def test_a_rollout_of_a_job_that_ended_is_not_active() -> None:
    job = a_job(phase="succeeded", rollout={"index": 2, "total": 2}, rollouts=[a_rollout(2, ended=False)])
    assert row_json(only_row([a_cell()], [job]), NOW)["job"]["rolloutActive"] is False


def test_the_latest_verdicts_are_listed_newest_first_with_who_marked_them() -> None:
    history = [a_rollout(i, 9, outcome="success" if i % 2 else "failure", by=f"op{i}") for i in range(1, 8)]
    job = a_job(rollout={"index": 8, "total": 9}, rollouts=[*history, a_rollout(8, 9, ended=False)])
    verdicts = row_json(only_row([a_cell()], [job]), NOW)["job"]["verdicts"]
    assert [(v["index"], v["outcome"], v["by"]) for v in verdicts] == [
        (7, "success", "op7"), (6, "failure", "op6"), (5, "success", "op5"), (4, "failure", "op4"),
        (3, "success", "op3")]
    assert verdicts[0]["at"] == "2027-01-15T07:58:30.000Z" and verdicts[0]["total"] == 9


def test_the_monitor_s_verdicts_are_listed_with_their_score_and_an_overrule_says_what_it_overruled() -> None:
    history = [a_rollout(1, 3, outcome="success", by="monitor", monitor=("success", 0.93)),
               a_rollout(2, 3, outcome="failure", by="ana", monitor=("success", 0.61)),
               a_rollout(3, 3, outcome="success", by="bo")]
    job = a_job(rollout={"index": 3, "total": 3}, rollouts=history)
    verdicts = row_json(only_row([a_cell()], [job]), NOW)["job"]["verdicts"]
    assert [(v["index"], v["by"], v["monitor"], v["score"], v["overruled"]) for v in verdicts] == [
        (3, "bo", None, None, False), (2, "ana", "success", 0.61, True), (1, "monitor", "success", 0.93, False)]
    # What an overrule of each names: the rollout's index and start, as the status has them.
    assert verdicts[2]["request"] == "1@2027-01-15T07:58:00.000Z"


@pytest.mark.parametrize("rows", ["x", [None, "x", {"index": "one", "outcome": "success"},
                                        {"index": 1, "outcome": "<b>won</b>"}, a_rollout(1)]])
def test_a_malformed_history_shows_no_verdicts(rows: object) -> None:
    job = a_job(rollout={"index": 1, "total": 2}, rollouts=rows)  # type: ignore[arg-type]
    assert row_json(only_row([a_cell()], [job]), NOW)["job"]["verdicts"] == []


def test_only_false_conditions_are_listed_with_their_reason() -> None:
    cell = a_cell(extra_conditions=({"type": "CamerasReady", "status": "False", "reason": "NoFrames",
                                     "message": "camera front gave no frame"},))
    row = only_row([cell])
    assert [(c.type, c.reason) for c in row.false_conditions] == [("CamerasReady", "NoFrames")]


def test_the_interlock_state_comes_from_the_interlock_clear_condition() -> None:
    assert only_row([a_cell(interlock="False")]).interlock == "tripped"
    assert only_row([a_cell(interlock="True")]).interlock == "clear"


def test_heartbeat_age_is_counted_from_the_frozen_clock() -> None:
    assert only_row([a_cell()]).heartbeat_age_s == 0.0
    assert only_row([a_cell(heartbeat=None)]).heartbeat_age_s is None


def test_fleet_filters_by_site_label_and_name_substring() -> None:
    cells = [a_cell("so101-a", site="lab-1"), a_cell("so101-b", site="lab-2"), a_cell("aloha-c", site="lab-1")]
    assert [r.name for r in build_fleet(cells, [], {}, NOW, site="lab-1")] == ["aloha-c", "so101-a"]
    assert [r.name for r in build_fleet(cells, [], {}, NOW, query="SO101")] == ["so101-a", "so101-b"]


def test_a_pending_reset_shows_with_its_request_and_the_time_left() -> None:
    pending = pending_from_notice("so101-a", a_notice(), 30, NOW - 10)
    row = row_json(only_row([a_cell()], [a_job()], {"so101-a": pending}), NOW)
    assert row["reset"] == {"request": "job-uid-1@2027-01-15T07:59:59+00:00", "secondsLeft": 20.0}


def test_a_reset_past_its_timeout_is_not_shown() -> None:
    pending = pending_from_notice("so101-a", a_notice(), 30, NOW - 31)
    assert only_row([a_cell()], [a_job()], {"so101-a": pending}).reset is None


def test_a_reset_announced_for_another_job_is_not_shown() -> None:
    pending = pending_from_notice("so101-a", a_notice(job_id="previous-job"), 30, NOW)
    assert only_row([a_cell()], [a_job()], {"so101-a": pending}).reset is None


def test_a_reset_of_a_job_that_ended_is_not_shown() -> None:
    pending = pending_from_notice("so101-a", a_notice(), 30, NOW)
    assert only_row([a_cell()], [a_job(phase="succeeded")], {"so101-a": pending}).reset is None


@pytest.mark.parametrize("notice", [{}, {"namespace": "a", "job": 3, "at": "x"}, {"namespace": "a", "job": "j"},
                                    {"namespace": "a", "job": "j" * 300, "at": "x"}])
def test_a_malformed_notice_makes_no_pending_reset(notice: dict) -> None:
    assert pending_from_notice("so101-a", notice, 30, NOW) is None


def test_the_page_never_gets_job_args_image_or_secrets() -> None:
    text = json.dumps(row_json(only_row([a_cell()], [a_job()]), NOW))
    assert "do-not-show" not in text and "secret-image" not in text


def test_the_request_id_the_agent_names_in_its_notice_is_the_one_used() -> None:
    notice = {**a_notice(), "request": "job-uid-1@agent-named"}
    assert pending_from_notice("so101-a", notice, 30, NOW).request_id == "job-uid-1@agent-named"


def test_a_notice_first_heard_as_a_repeat_counts_the_timeout_from_when_the_wait_began() -> None:
    pending = pending_from_notice("so101-a", {**a_notice(), "elapsed": 12.5}, 30, NOW)
    assert pending.seconds_left(NOW) == 17.5


@pytest.mark.parametrize("elapsed", [-5, float("nan"), float("inf"), True, "12", None, 10**400])
def test_an_elapsed_that_is_not_a_duration_counts_the_timeout_from_when_the_notice_was_heard(elapsed: object) -> None:
    pending = pending_from_notice("so101-a", {**a_notice(), "elapsed": elapsed}, 30, NOW)
    assert pending.seconds_left(NOW) == 30


def test_an_elapsed_past_the_timeout_shows_a_reset_already_over() -> None:
    assert pending_from_notice("so101-a", {**a_notice(), "elapsed": 1e308}, 30, NOW).expired(NOW)


def test_the_queue_at_a_cell_shows_how_many_wait_and_in_how_long_its_job_ends_by_the_fms_clock() -> None:
    queue = {"waitingJobs": 3, "likelyFree": "2027-01-15T08:04:00Z", "latestFree": "2027-01-15T08:12:00Z"}
    row = row_json(only_row([a_cell(queue=queue)], [a_job()]), NOW)
    assert row["queue"] == {"waitingJobs": 3, "likelyFreeInS": 240.0, "latestFreeInS": 720.0}


def test_an_overdue_job_ends_any_moment_a_free_cell_has_no_end_and_no_summary_shows_none() -> None:
    overdue = {"waitingJobs": 1, "likelyFree": "2027-01-15T07:50:00Z", "latestFree": "2027-01-15T07:55:00Z"}
    assert row_json(only_row([a_cell(queue=overdue)]), NOW)["queue"] == {
        "waitingJobs": 1, "likelyFreeInS": 0.0, "latestFreeInS": 0.0}
    assert row_json(only_row([a_cell(queue={"waitingJobs": 0})]), NOW)["queue"] == {
        "waitingJobs": 0, "likelyFreeInS": None, "latestFreeInS": None}
    assert row_json(only_row([a_cell()]), NOW)["queue"] is None


def test_a_malformed_time_in_the_queue_summary_hides_only_that_time() -> None:
    queue = {"waitingJobs": 2, "likelyFree": "soon", "latestFree": "2027-01-15T08:12:00Z"}
    row = row_json(only_row([a_cell(queue=queue)]), NOW)
    assert row["queue"] == {"waitingJobs": 2, "likelyFreeInS": None, "latestFreeInS": 720.0}
    assert row["phase"] == "Busy"  # the rest of the cell still shows


def test_a_row_says_when_a_resting_cell_is_back_and_which_cell_is_a_preflight_twin() -> None:
    resting = a_cell(phase="Resting", job=None)
    resting["status"]["dutyCycle"] = {"workingSince": "2027-01-15T02:00:00+00:00",
                                      "restingUntil": "2027-01-15T08:12:00+00:00"}
    twin = a_cell("twin", phase="Ready", job=None)
    twin["spec"].update(simulated=True, preflight=True)
    rows = [row_json(only_row([cell]), NOW) for cell in (resting, twin)]
    assert (rows[0]["restEndsInS"], rows[0]["preflight"]) == (720.0, False)
    assert (rows[1]["restEndsInS"], rows[1]["preflight"]) == (None, True)

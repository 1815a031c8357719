"""What the CLI prints and returns: tables, -o json shapes, result exit codes, log lines."""

from __future__ import annotations

import io
import json
from datetime import datetime, timedelta, timezone

import pytest
from armnet_client.cli.printer import LogPrinter, parse_since, tail, tail_batches
from armnet_client.logwire import CaughtUp, LogLine
from armnet_client.mapping import cell_view_of, job_from_robotjob, result_from_robotjob, view_of
from armnet_client.render import (
    age,
    cell_document,
    cells_table,
    job_document,
    jobs_table,
    result_document,
    result_exit_code,
)
from armnet_client.resources import Cell, RobotJob
from armnet_core.models import JobStatus

from .builders import a_cell, a_robotjob

pytestmark = pytest.mark.unit

NOW = datetime(2026, 11, 24, 10, 5, 0, tzinfo=timezone.utc)  # noqa: UP017


def job(**status: object) -> RobotJob:
    return RobotJob.model_validate(a_robotjob(**status))


@pytest.mark.parametrize(("status", "code"), [
    (JobStatus.SUCCEEDED, 0), (JobStatus.FAILED, 1), (JobStatus.TIMEOUT, 1), (JobStatus.CANCELLED, 1),
    (JobStatus.SUBMITTED, 2), (JobStatus.QUEUED, 2), (JobStatus.DISPATCHED, 2), (JobStatus.RUNNING, 2),
])
def test_result_exit_codes_are_0_succeeded_1_other_terminal_2_unfinished(status: JobStatus, code: int) -> None:
    assert result_exit_code(status) == code


@pytest.mark.parametrize(("delta", "text"), [
    (timedelta(seconds=5), "5s"), (timedelta(minutes=5), "5m"), (timedelta(hours=3), "3h"),
    (timedelta(days=3), "3d"), (timedelta(seconds=-5), "0s"),
])
def test_ages_are_compact_like_kubectl(delta: timedelta, text: str) -> None:
    assert age(NOW - delta, NOW) == text


def test_a_queued_job_shows_its_reason_and_position() -> None:
    rows = jobs_table([view_of(job(phase="queued", queuedReason="AllCellsBusy", queuePosition=2))],
                      NOW).splitlines()

    assert rows[0].split() == ["NAME", "STATUS", "CELL", "EMBODIMENT", "QUEUE", "AGE"]
    assert rows[1].split() == ["pick-1", "queued", "<none>", "lerobot/so-101", "AllCellsBusy", "#2", "5m"]


def test_a_job_waiting_for_busy_cells_shows_when_it_starts_at_the_latest() -> None:
    body = job(phase="queued", queuedReason="AllCellsBusy", queuePosition=1, estimatedStart="2026-11-24T10:17:00Z")
    row = jobs_table([view_of(body)], NOW).splitlines()[1]
    assert "AllCellsBusy #1, starts within 12m" in row


def test_a_job_likely_to_start_before_its_latest_start_shows_both() -> None:
    body = job(phase="queued", queuedReason="AllCellsBusy", queuePosition=1, estimatedStart="2026-11-24T10:17:00Z",
               likelyStart="2026-11-24T10:09:00Z")
    row = jobs_table([view_of(body)], NOW).splitlines()[1]
    assert "AllCellsBusy #1, likely in 4m, starts within 12m" in row


def test_a_running_job_shows_its_cell_and_no_queue() -> None:
    row = jobs_table([view_of(job(phase="running", cellName="cell-a"))], NOW).splitlines()[1]

    assert row.split() == ["pick-1", "running", "cell-a", "lerobot/so-101", "-", "5m"]


def test_wide_adds_task_priority_image_progress_with_rollout_and_output() -> None:
    rows = jobs_table([view_of(job(phase="running", progress="grasp", rollout={"index": 3, "total": 10}))],
                      NOW, wide=True).splitlines()

    assert rows[0].split()[-5:] == ["TASK", "PRIORITY", "IMAGE", "PROGRESS", "OUTPUT"]
    assert rows[1].endswith("grasp [rollout 3/10]   -")


@pytest.mark.parametrize(("artifacts", "shown"), [
    ({"phase": "Uploaded", "files": 12, "bytes": 3_400_000, "complete": True}, "12 files, 3.4 MB"),
    ({"phase": "Uploaded", "files": 1, "bytes": 999, "complete": False}, "1 files, 999 B (incomplete)"),
    ({"phase": "Uploaded", "files": 2, "bytes": 5 * 10**12, "complete": True}, "2 files, 5000.0 GB"),
    ({"phase": "Retrying", "message": "the store did not answer"}, "Retrying"),
    ({"phase": "Discarded"}, "Discarded"),
])
def test_wide_shows_where_the_output_went(artifacts: dict[str, object], shown: str) -> None:
    rows = jobs_table([view_of(job(phase="succeeded", artifacts=artifacts))], NOW, wide=True).splitlines()

    assert rows[1].endswith(shown)


def test_the_job_json_carries_the_output_location_and_manifest() -> None:
    body = job(phase="succeeded", artifacts={"phase": "Uploaded", "location": "s3://b/team/u/",
                                             "manifest": "s3://b/team/u/manifest.json", "files": 2, "bytes": 10,
                                             "complete": True, "leftOut": 1, "message": "1 entries were not stored"})

    document = json.loads(json.dumps(job_document(job_from_robotjob(body), view_of(body))))

    assert document["artifacts"]["manifest"] == "s3://b/team/u/manifest.json"
    assert document["artifacts"]["leftOut"] == 1


def test_wide_counts_the_rollouts_the_cell_operator_marked() -> None:
    marked = [{"index": i, "total": 3, "outcome": o, "startedAt": "2026-03-01T12:00:00.000Z"}
              for i, o in ((1, "success"), (2, "failure"), (3, "unmarked"))]
    rows = jobs_table([view_of(job(phase="running", progress="grasp", rollout={"index": 3, "total": 3},
                                   rollouts=marked))], NOW, wide=True).splitlines()

    assert rows[1].endswith("grasp [rollout 3/3] [marked: 1 success, 1 failure]   -")


def test_wide_counts_the_operator_s_overrules_of_the_completion_monitor() -> None:
    monitor = {"outcome": "failure", "score": 0.1, "at": "2026-03-01T12:00:01.000Z"}
    marked = [{"index": 1, "total": 2, "outcome": "success", "markedBy": "ana", "monitor": monitor,
               "startedAt": "2026-03-01T12:00:00.000Z"},
              {"index": 2, "total": 2, "outcome": "failure", "markedBy": "monitor", "monitor": monitor,
               "startedAt": "2026-03-01T12:00:02.000Z"}]
    view = view_of(job(phase="succeeded", rollouts=marked))

    assert jobs_table([view], NOW, wide=True).splitlines()[1].endswith(
        "[marked: 1 success, 1 failure; 1 overruled]   -")
    rows = json.loads(json.dumps(job_document(job_from_robotjob(job(phase="succeeded", rollouts=marked)), view)))
    assert rows["rollouts"][0]["monitor"]["outcome"] == "failure"


def test_the_job_json_lists_the_rollout_history_with_who_marked_each() -> None:
    body = job(phase="running", rollouts=[{"index": 1, "total": 2, "outcome": "failure", "markedBy": "ana",
                                           "markedAt": "2026-03-01T12:00:01.500Z",
                                           "startedAt": "2026-03-01T12:00:00.000Z"}])

    [entry] = json.loads(json.dumps(job_document(job_from_robotjob(body), view_of(body))))["rollouts"]

    assert (entry["index"], entry["outcome"], entry["markedBy"], entry["endedAt"]) == (1, "failure", "ana", None)
    assert entry["markedAt"].startswith("2026-03-01T12:00:01.5")


def test_columns_are_aligned() -> None:
    rows = jobs_table([view_of(job()), view_of(RobotJob.model_validate(a_robotjob(name="a-much-longer-name")))],
                      NOW).splitlines()

    assert len({row.index("submitted") for row in rows[1:]}) == 1


def test_the_job_json_shape_is_the_sdk_job_plus_queue_and_progress() -> None:
    body = job(phase="queued", jobId="0f3c-uid", queuedReason="AllCellsBusy", queuePosition=1,
               estimatedStart="2026-01-01T12:10:00Z", likelyStart="2026-01-01T12:04:00Z")

    document = json.loads(json.dumps(job_document(job_from_robotjob(body), view_of(body))))

    assert set(document) == {"id", "spec", "status", "created_at", "updated_at", "cell_id", "result",
                             "namespace", "jobId", "queue", "progress", "rollout", "rollouts", "cancelRequested", "artifacts",
                             "preflight"}
    assert document["status"] == "queued"
    assert document["queue"] == {"reason": "AllCellsBusy", "position": 1, "estimatedStart": "2026-01-01T12:10:00+00:00",
                                 "likelyStart": "2026-01-01T12:04:00+00:00"}
    assert document["spec"]["embodiment"] == "lerobot/so-101"


def test_the_result_json_is_the_job_result_plus_finished() -> None:
    body = job(phase="failed", result={"exitCode": 2, "error": "image pull failed"})

    document = result_document(result_from_robotjob(body), JobStatus.FAILED)

    assert document["finished"] is True
    assert (document["status"], document["exit_code"], document["error"]) == ("failed", 2, "image pull failed")
    assert {"stdout", "stderr", "traceback", "return_value", "started_at", "finished_at"} <= set(document)


def test_an_unfinished_result_json_says_so() -> None:
    assert result_document(None, JobStatus.RUNNING) == {"status": "running", "finished": False}


def test_the_cells_table_shows_failing_conditions_and_heartbeat_age() -> None:
    cell = cell_view_of(Cell.model_validate(a_cell(
        phase="Faulted", currentJob="team-a/pick-1", lastHeartbeatTime="2026-11-24T10:04:30Z",
        conditions=[{"type": "HardwareReady", "status": "False", "reason": "DeviceLost"}])))

    rows = cells_table([cell], NOW).splitlines()

    assert rows[1].split() == ["cell-1", "Faulted", "lerobot/so-101", "<any>", "team-a/pick-1",
                               "HardwareReady(DeviceLost)", "30s", "ago"]
    assert cell_document(cell)["failingConditions"] == [
        {"type": "HardwareReady", "reason": "DeviceLost", "message": None}]


def test_the_cells_table_says_when_a_rest_ends_and_which_cells_run_preflights_only() -> None:
    resting = a_cell("arm-1", phase="Resting", dutyCycle={"workingSince": "2026-11-24T04:00:00Z",
                                                           "restingUntil": "2026-11-24T10:17:00Z"})
    twin = a_cell("twin-1", phase="Ready")
    twin["spec"].update(simulated=True, preflight=True)
    cells = [cell_view_of(Cell.model_validate(body)) for body in (resting, twin)]

    rows = [row.split() for row in cells_table(cells, NOW).splitlines()[1:]]

    assert [row[:2] for row in rows] == [["arm-1", "Resting(12m)"], ["twin-1", "Ready,Preflight"]]
    assert cell_document(cells[0])["restingUntil"] == "2026-11-24T10:17:00+00:00"
    assert cell_document(cells[1])["preflight"] is True


def line(kind: str, text: str, data: object = None) -> LogLine:
    return LogLine(kind=kind, text=text, time=NOW, data=data)


def test_output_lines_are_timestamped_in_utc_and_stderr_is_marked() -> None:
    out = io.StringIO()
    printer = LogPrinter(out, live=False)

    printer.show(line("stdout", "hello"))
    printer.show(line("stderr", "oops"))

    assert out.getvalue() == "2026-11-24T10:05:00.000Z hello\n2026-11-24T10:05:00.000Z [stderr] oops\n"


def test_on_a_terminal_progress_is_one_live_line_redrawn_under_the_output() -> None:
    out = io.StringIO()
    printer = LogPrinter(out, live=True, timestamps=False)

    printer.show(line("progress", "step 1"))
    printer.show(line("stdout", "x"))
    printer.show(line("progress", "step 2"))
    printer.close()

    assert out.getvalue() == "\r\x1b[2Kstep 1\r\x1b[2Kx\nstep 1\r\x1b[2Kstep 2\n"


def test_after_rollout_begin_progress_shows_the_rollout_index() -> None:
    out = io.StringIO()
    printer = LogPrinter(out, live=False, timestamps=False)

    printer.show(line("status", "status: running", {"phase": "running", "detail": {"rollout": {"index": 3, "total": 10}}}))
    printer.show(line("progress", "grasping"))

    assert out.getvalue().splitlines() == ["[status: running]", "[progress] [rollout 3/10] grasping"]


def test_tail_keeps_the_last_n_stored_lines_then_everything_live() -> None:
    events = [line("stdout", str(i)) for i in range(5)] + [CaughtUp(), line("stdout", "live")]

    assert [x.text for x in tail(events, 2)] == ["3", "4", "live"]
    assert [x.text for x in tail(events, None)] == ["0", "1", "2", "3", "4", "live"]
    assert [x.text for x in tail(events, 0)] == ["live"]


class Writes(io.StringIO):
    """A text stream that counts writes and flushes (a pipe pays a system call for each flush)."""

    def __init__(self) -> None:
        super().__init__()
        self.writes = self.flushes = 0

    def write(self, text: str) -> int:
        self.writes += 1
        return super().write(text)

    def flush(self) -> None:
        self.flushes += 1


def test_lines_that_arrived_together_are_printed_with_one_write_and_one_flush() -> None:
    out = Writes()
    printer = LogPrinter(out, live=False)

    printer.show_all([line("stdout", "a"), line("stderr", "b"), line("progress", "p"), line("stdout", "c")])

    assert out.getvalue().splitlines() == ["2026-11-24T10:05:00.000Z a", "2026-11-24T10:05:00.000Z [stderr] b",
                                           "2026-11-24T10:05:00.000Z [progress] p", "2026-11-24T10:05:00.000Z c"]
    assert (out.writes, out.flushes) == (1, 1)


def test_a_line_time_in_another_zone_is_printed_in_utc_to_the_millisecond() -> None:
    moment = datetime(2026, 11, 24, 11, 5, 0, 123999, tzinfo=timezone(timedelta(hours=1)))
    out = io.StringIO()

    LogPrinter(out, live=False).show(LogLine("stdout", "x", moment))

    assert out.getvalue() == "2026-11-24T10:05:00.123Z x\n"


def test_tail_over_batches_keeps_the_last_n_stored_lines_then_each_live_batch_whole() -> None:
    batches = [[line("stdout", "0"), line("stdout", "1")], [line("stdout", "2"), CaughtUp()],
               [line("stdout", "live 1"), line("stdout", "live 2")]]

    assert [[x.text for x in b] for b in tail_batches(batches, 2)] == [["1", "2"], ["live 1", "live 2"]]
    assert [[x.text for x in b] for b in tail_batches(batches, None)] == [["0", "1"], ["2"], ["live 1", "live 2"]]


def test_since_takes_durations_and_times_with_a_zone() -> None:
    assert parse_since("10m", NOW) == NOW - timedelta(minutes=10)
    assert parse_since("2026-11-24T09:00:00Z", NOW) == datetime(2026, 11, 24, 9, tzinfo=timezone.utc)  # noqa: UP017
    with pytest.raises(ValueError, match="time zone"):
        parse_since("2026-11-24T09:00:00", NOW)
    with pytest.raises(ValueError, match="duration like 10m"):
        parse_since("yesterday", NOW)


def test_a_finished_jobs_status_line_says_why_it_ended() -> None:
    out = io.StringIO()
    printer = LogPrinter(out, live=False, timestamps=False)

    printer.show(line("status", "status: failed", {"phase": "failed", "detail": {
        "error": "image localhost/x:404 not found on this node; push it to a registry the node can pull from"}}))
    printer.show(line("status", "status: succeeded", {"phase": "succeeded", "detail": {"exitCode": 0}}))

    assert out.getvalue().splitlines() == [
        "[status: failed] image localhost/x:404 not found on this node; push it to a registry the node can pull from",
        "[status: succeeded]"]


def test_tail_keeps_a_finished_jobs_status_from_the_backlog() -> None:
    end = line("status", "status: cancelled", {"phase": "cancelled", "detail": {"error": "stopped"}})
    events = [line("stdout", str(i)) for i in range(3)] + [end]

    assert [x.text for x in tail(events, 1)] == ["2", "status: cancelled"]
    assert [x.text for x in tail([*events, CaughtUp()], 0)] == ["status: cancelled"]


def test_wide_cells_name_the_completion_monitor_and_a_malformed_one_never_fails_the_list() -> None:
    body = a_cell(phase="Ready")
    body["spec"]["completion"] = {"scorer": "region", "camera": "front", "colour": {"hueMin": 0}}
    plain, odd = a_cell("cell-2", phase="Ready"), a_cell("cell-3", phase="Ready")
    odd["spec"]["completion"] = "yes please"
    cells = [cell_view_of(Cell.model_validate(b)) for b in (body, plain, odd)]

    rows = [r.split() for r in cells_table(cells, NOW, wide=True).splitlines()]

    assert rows[0][-2:] == ["NODE", "COMPLETION"]
    assert [r[-1] for r in rows[1:]] == ["region(front)", "operator", "?(?)"]
    assert cell_document(cells[0])["completion"] == {"scorer": "region", "camera": "front"}
    assert cell_document(cells[1])["completion"] is None


def test_wide_cells_say_how_many_jobs_wait_and_when_the_job_likely_ends_and_at_the_latest() -> None:
    busy, free, unseen = a_cell(phase="Busy"), a_cell("cell-2", phase="Ready"), a_cell("cell-3", phase="Ready")
    busy["status"]["queue"] = {"waitingJobs": 2, "likelyFree": (NOW + timedelta(minutes=4)).isoformat(),
                               "latestFree": (NOW + timedelta(minutes=12)).isoformat()}
    free["status"]["queue"] = {"waitingJobs": 0}
    cells = [cell_view_of(Cell.model_validate(b)) for b in (busy, free, unseen)]

    rows = [r.split() for r in cells_table(cells, NOW, wide=True).splitlines()]

    assert rows[0][-4:] == ["WAITING", "FREE-IN", "NODE", "COMPLETION"]
    assert [r[-4:-2] for r in rows[1:]] == [["2", "4m/12m"], ["0", "-"], ["-", "-"]]
    assert cell_document(cells[0])["queue"] == {"waitingJobs": 2, "likelyFree": "2026-11-24T10:09:00Z",
                                                "latestFree": "2026-11-24T10:17:00Z"}
    assert cell_document(cells[2])["queue"] is None


def test_a_preempting_job_says_so_and_a_preempted_one_names_its_requeue() -> None:
    preemption = {"requestedAt": "2026-11-24T10:00:00Z", "forJob": "team-b/x", "message": "reclaimed",
                  "episodeWaitSeconds": 120}
    running = jobs_table([view_of(job(phase="running", cellName="cell-a", preemption=preemption))], NOW)
    assert "running (preempting)" in running.splitlines()[1]
    preempted = jobs_table([view_of(job(phase="preempted", cellName="cell-a", requeuedAs="pick-r1"))], NOW)
    assert "requeued as pick-r1" in preempted.splitlines()[1]


def test_a_job_in_its_preflight_names_it_and_one_whose_preflight_failed_says_so() -> None:
    running = {"phase": "Running", "job": "pick-preflight", "startedAt": "2026-11-24T10:00:00Z"}
    waiting = view_of(job(phase="queued", queuedReason="PreflightRunning", queuePosition=3, preflight=running))
    assert "PreflightRunning #3, pre-flight pick-preflight" in jobs_table([waiting], NOW).splitlines()[1]
    failed = {"phase": "Failed", "job": "pick-preflight", "message": "the pre-flight job pick-preflight failed"}
    body = job(phase="failed", preflight=failed)
    assert "pre-flight pick-preflight failed" in jobs_table([view_of(body)], NOW).splitlines()[1]
    document = json.loads(json.dumps(job_document(job_from_robotjob(body), view_of(body))))
    assert document["preflight"] == failed
    assert json.loads(json.dumps(job_document(job_from_robotjob(job()), view_of(job()))))["preflight"] is None

"""A job's rollout history (``status.rollouts``): what each begin, end and verdict makes of it."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, datetime, timedelta

import pytest
from armnet_core import JobResult, JobStatus
from armnet_node.model import parse_job
from armnet_node.report import progress_patch, terminal_patch
from armnet_node.rollout_history import (
    MAX_ENTRIES,
    MONITOR,
    Begun,
    Ended,
    History,
    Judged,
    Marked,
    MonitorMark,
    Outcome,
    Overruled,
    RolloutChange,
    accepts_verdict,
    apply,
    as_status,
    from_status,
    overruled,
)
from armnet_node.rollout_recorder import RolloutRecorder

pytestmark = pytest.mark.unit

T0 = datetime(2026, 3, 1, 12, 0, 0, tzinfo=UTC)


def at(seconds: float) -> datetime:
    return T0 + timedelta(seconds=seconds)


def fold(*changes: RolloutChange, history: History = ()) -> History:
    for change in changes:
        history = apply(history, change)
    return history


def test_a_begin_adds_an_open_unmarked_rollout() -> None:
    [entry] = fold(Begun(1, 3, at(0)))
    assert (entry.index, entry.total, entry.outcome, entry.open) == (1, 3, Outcome.UNMARKED, True)


def test_an_end_closes_the_open_rollout() -> None:
    [entry] = fold(Begun(1, 3, at(0)), Ended(at(5)))
    assert entry.ended_at == at(5) and not entry.open


def test_an_end_with_no_open_rollout_changes_nothing() -> None:
    history = fold(Begun(1, 3, at(0)), Ended(at(5)))
    assert apply(history, Ended(at(9))) is history
    assert apply((), Ended(at(9))) == ()


def test_the_same_begin_seen_twice_adds_one_rollout() -> None:
    history = fold(Begun(1, 3, at(0)))
    assert apply(history, Begun(1, 3, at(0))) is history


def test_a_begin_while_a_rollout_is_open_closes_it_at_the_new_begin() -> None:
    first, second = fold(Begun(1, 3, at(0)), Begun(2, 3, at(4)))
    assert first.ended_at == at(4) and second.open and second.index == 2


def test_a_verdict_marks_the_open_rollout_with_who_marked_it_and_when() -> None:
    [entry] = fold(Begun(1, 3, at(0)), Marked(False, "ana", at(2), rollout=1))
    assert (entry.outcome, entry.marked_by, entry.marked_at, entry.open) == (Outcome.FAILURE, "ana", at(2), True)


def test_a_verdict_naming_no_rollout_marks_the_open_one() -> None:
    [entry] = fold(Begun(1, 3, at(0)), Marked(True, "ana", at(2)))
    assert entry.outcome is Outcome.SUCCESS


def test_a_verdict_naming_no_rollout_with_none_open_changes_nothing() -> None:
    history = fold(Begun(1, 3, at(0)), Ended(at(1)))
    assert apply(history, Marked(True, "ana", at(2))) is history


def test_a_verdict_for_a_rollout_that_just_ended_marks_that_rollout_not_the_next() -> None:
    first, second = fold(Begun(1, 2, at(0)), Ended(at(1)), Begun(2, 2, at(2)), Marked(True, "ana", at(3), rollout=1))
    assert first.outcome is Outcome.SUCCESS and second.outcome is Outcome.UNMARKED


def test_a_verdict_for_a_rollout_never_begun_changes_nothing() -> None:
    history = fold(Begun(1, 3, at(0)))
    assert apply(history, Marked(True, "ana", at(2), rollout=7)) is history
    assert apply((), Marked(True, "ana", at(2))) == ()


def test_a_second_verdict_on_one_rollout_replaces_the_first() -> None:
    [entry] = fold(Begun(1, 3, at(0)), Marked(True, "ana", at(1), 1), Marked(False, "bo", at(2), 1))
    assert (entry.outcome, entry.marked_by) == (Outcome.FAILURE, "bo")


def test_only_the_newest_rollouts_are_kept() -> None:
    history = fold(*(Begun(i, 0, at(i)) for i in range(MAX_ENTRIES + 7)))
    assert len(history) == MAX_ENTRIES
    assert [e.index for e in history] == list(range(7, MAX_ENTRIES + 7))


def test_a_hostile_operator_name_is_recorded_without_control_characters_and_bounded() -> None:
    [entry] = fold(Begun(1, 1, at(0)), Marked(True, "ana\n\x1b[31m" + "x" * 500, at(1)))
    assert entry.marked_by is not None
    assert entry.marked_by.startswith("ana[31m") and len(entry.marked_by) == 128


def test_the_status_form_names_every_field_and_leaves_out_the_absent_ones() -> None:
    history = fold(Begun(1, 2, at(0)), Marked(False, "ana", at(1.5), 1), Ended(at(2)), Begun(2, 2, at(3)))
    assert as_status(history) == [
        {"index": 1, "total": 2, "outcome": "failure", "startedAt": "2026-03-01T12:00:00.000Z",
         "outcomeControls": True, "markedBy": "ana", "markedAt": "2026-03-01T12:00:01.500Z",
         "endedAt": "2026-03-01T12:00:02.000Z"},
        {"index": 2, "total": 2, "outcome": "unmarked", "startedAt": "2026-03-01T12:00:03.000Z",
         "outcomeControls": True},
    ]


def test_the_status_form_reads_back_as_the_same_history() -> None:
    history = fold(Begun(1, 2, at(0)), Marked(False, "ana", at(1.5), 1), Ended(at(2)), Begun(2, 2, at(3), False))
    assert from_status(as_status(history)) == history


@pytest.mark.parametrize("value", [None, "x", 5, {"index": 1}])
def test_a_status_that_is_no_list_reads_as_no_history(value: object) -> None:
    assert from_status(value) == ()


def test_malformed_status_entries_are_skipped() -> None:
    good = {"index": 1, "total": 2, "outcome": "success", "startedAt": "2026-03-01T12:00:00Z"}
    bad = [None, "x", {"index": True, "total": 1, "startedAt": "2026-03-01T12:00:00Z"},
           {"index": 1, "total": 1, "startedAt": "yesterday"}, {"index": 1, "startedAt": "2026-03-01T12:00:00Z"}]
    [entry] = from_status([*bad, good])
    assert entry.outcome is Outcome.SUCCESS


def test_an_unknown_outcome_reads_as_unmarked() -> None:
    [entry] = from_status([{"index": 1, "total": 2, "outcome": "maybe", "startedAt": "2026-03-01T12:00:00Z"}])
    assert entry.outcome is Outcome.UNMARKED


def test_a_restarted_agent_reads_the_history_from_the_job() -> None:
    history = fold(Begun(1, 2, at(0)), Marked(True, "ana", at(1), 1))
    job = parse_job({"metadata": {"namespace": "t", "name": "j", "uid": "u"},
                     "spec": {"image": "example.com/pick:1", "embodiment": "lerobot/so-101"},
                     "status": {"phase": "running", "rollouts": as_status(history)}})
    assert job.rollouts == history


def test_the_progress_write_carries_the_whole_history_and_only_when_given() -> None:
    rows = as_status(fold(Begun(1, 2, at(0))))
    assert progress_patch("x", {"index": 1, "total": 2}, rows)["status"]["rollouts"] == rows
    assert "rollouts" not in progress_patch("x", {"index": 1, "total": 2})["status"]


def test_the_terminal_write_carries_the_final_history() -> None:
    rows = as_status(fold(Begun(1, 2, at(0)), Ended(at(1))))
    result = JobResult(status=JobStatus.SUCCEEDED, exit_code=0, started_at=T0, finished_at=T0)
    assert terminal_patch("7", result, None, rows)["status"]["rollouts"] == rows
    assert "rollouts" not in terminal_patch("7", result, None, [])["status"]


@dataclass(frozen=True)
class Event:
    """Shaped like ``connector.cell.RolloutEvent``."""

    kind: str
    at: float
    index: int | None = None
    total: int | None = None
    outcome_controls: bool | None = None
    success: bool | None = None
    score: float | None = None
    frame_at: float | None = None


class Connector:
    def __init__(self) -> None:
        self.events: list[Event] = []

    def __call__(self) -> list[Event]:
        return list(self.events)


def test_the_recorder_takes_each_connector_event_once() -> None:
    connector = Connector()
    recorder = RolloutRecorder(connector)
    connector.events += [Event("begin", at(0).timestamp(), 1, 2)]
    assert recorder.sync() is True
    assert recorder.sync() is False
    connector.events += [Event("end", at(1).timestamp()), Event("begin", at(2).timestamp(), 2, 2)]
    recorder.sync()
    assert [(e.index, e.open) for e in recorder.history] == [(1, False), (2, True)]


def test_a_rollout_begun_without_outcome_controls_is_recorded_so() -> None:
    connector = Connector()
    recorder = RolloutRecorder(connector)
    connector.events += [Event("begin", at(0).timestamp(), 1, 2, outcome_controls=False),
                         Event("begin", at(1).timestamp(), 2, 2)]  # a connector that did not say: the SDK default
    recorder.sync()
    assert [e.outcome_controls for e in recorder.history] == [False, True]


def test_a_verdict_catches_up_with_the_connector_before_it_is_recorded() -> None:
    connector = Connector()
    recorder = RolloutRecorder(connector, clock=lambda: at(3))
    connector.events += [Event("begin", at(0).timestamp(), 1, 2), Event("end", at(1).timestamp()),
                         Event("begin", at(2).timestamp(), 2, 2)]
    recorder.verdict(True, "ana", 2)  # the once-a-second poll has not run since the job began rollout 2
    assert [(e.index, e.outcome, e.marked_by) for e in recorder.history] == [
        (1, Outcome.UNMARKED, None), (2, Outcome.SUCCESS, "ana")]


def test_the_recorder_offers_a_history_to_write_until_it_is_written() -> None:
    connector = Connector()
    recorder = RolloutRecorder(connector)
    assert recorder.unwritten() is None
    connector.events += [Event("begin", at(0).timestamp(), 1, 2)]
    recorder.sync()
    history = recorder.unwritten()
    assert history is not None
    recorder.written(history)
    assert recorder.unwritten() is None


def test_a_history_read_back_after_a_restart_is_not_written_again_unchanged() -> None:
    seeded = fold(Begun(1, 2, at(0)))
    assert RolloutRecorder(Connector(), history=seeded).unwritten() is None


def test_events_that_fell_out_of_the_connectors_window_are_found_by_time() -> None:
    connector = Connector()
    recorder = RolloutRecorder(connector)
    connector.events += [Event("begin", at(0).timestamp(), 1, 2)]
    recorder.sync()
    connector.events = [Event("end", at(1).timestamp()), Event("begin", at(2).timestamp(), 2, 2)]
    recorder.sync()
    assert [(e.index, e.open) for e in recorder.history] == [(1, False), (2, True)]


def test_a_rollout_begun_without_outcome_controls_accepts_no_verdict_by_index_or_as_the_open_one() -> None:
    history = fold(Begun(index=1, total=2, at=at(0), outcome_controls=False))

    assert not accepts_verdict(history, 1)
    assert not accepts_verdict(history, None)


def test_a_rollout_with_outcome_controls_accepts_a_verdict_and_so_does_a_job_with_no_history() -> None:
    history = fold(Begun(index=1, total=2, at=at(0), outcome_controls=False), Ended(at=at(1)),
                   Begun(index=2, total=2, at=at(2)))

    assert accepts_verdict(history, 2) and accepts_verdict(history, None)
    assert accepts_verdict((), 1) and accepts_verdict((), None)


# -- the completion monitor's verdicts --------------------------------------------------------

def judged(index: int, success: bool, seconds: float, score: float = 0.9) -> Judged:
    return Judged(index, MonitorMark(success, score, at(seconds), at(seconds - 0.1)))


def test_the_monitor_s_verdict_is_the_outcome_of_an_unmarked_rollout_and_kept_beside_it() -> None:
    [entry] = fold(Begun(1, 2, at(0)), judged(1, True, 5), Ended(at(6)))
    assert (entry.outcome, entry.marked_by, entry.marked_at) == (Outcome.SUCCESS, MONITOR, at(5))
    assert entry.monitor == MonitorMark(True, 0.9, at(5), at(4.9))
    assert not overruled(entry)


def test_an_operator_s_mark_stands_against_a_later_monitor_verdict_and_is_an_overrule() -> None:
    [entry] = fold(Begun(1, 2, at(0)), Marked(False, "ana", at(3)), judged(1, True, 5))
    assert (entry.outcome, entry.marked_by) == (Outcome.FAILURE, "ana")
    assert entry.monitor is not None and entry.monitor.success is True
    assert overruled(entry)


def test_an_operator_overrules_the_monitor_after_it_judged_and_its_verdict_stays_on_record() -> None:
    [entry] = fold(Begun(1, 2, at(0)), judged(1, False, 5, score=0.1), Ended(at(6)), Marked(True, "ana", at(7), 1))
    assert (entry.outcome, entry.marked_by) == (Outcome.SUCCESS, "ana")
    assert entry.monitor is not None and (entry.monitor.success, entry.monitor.score) == (False, 0.1)
    assert overruled(entry)
    [agreeing] = fold(Begun(1, 2, at(0)), judged(1, True, 5), Marked(True, "ana", at(7)))
    assert not overruled(agreeing)


def test_an_operator_named_monitor_is_never_taken_for_the_monitor() -> None:
    [entry] = fold(Begun(1, 2, at(0)), Marked(True, "monitor", at(3)), judged(1, False, 5))
    assert (entry.outcome, entry.marked_by) == (Outcome.SUCCESS, "monitor (operator)")


def test_a_monitor_verdict_for_a_rollout_never_begun_changes_nothing() -> None:
    history = fold(Begun(1, 2, at(0)))
    assert apply(history, judged(7, True, 5)) is history


def test_the_monitor_s_verdict_reads_back_from_the_status() -> None:
    history = fold(Begun(1, 2, at(0)), judged(1, False, 5, score=0.123456), Marked(True, "ana", at(7)))
    [row] = as_status(history)
    assert row["monitor"] == {"outcome": "failure", "score": 0.1235, "at": "2026-03-01T12:00:05.000Z",
                              "frameAt": "2026-03-01T12:00:04.900Z"}
    [entry] = from_status(as_status(history))
    assert entry.monitor == MonitorMark(False, 0.1235, at(5), at(4.9))
    assert overruled(entry)
    [by_monitor] = from_status(as_status(fold(Begun(1, 2, at(0)), judged(1, True, 5))))
    assert by_monitor.marked_by == MONITOR and not by_monitor.marked_by_operator  # still the monitor's after a restart
    [malformed] = from_status([{**row, "monitor": {"outcome": "maybe", "score": "high"}}])
    assert malformed.monitor is None


def test_the_recorder_counts_each_overrule_once_in_either_order_and_not_again_after_a_restart() -> None:
    connector = Connector()
    overrules: list[int] = []
    recorder = RolloutRecorder(connector, clock=lambda: at(9), on_overrule=lambda: overrules.append(1))
    connector.events += [Event("begin", at(0).timestamp(), 1, 2),
                         Event("verdict", at(5).timestamp(), 1, success=False, score=0.2, frame_at=at(4).timestamp()),
                         Event("end", at(6).timestamp()), Event("begin", at(7).timestamp(), 2, 2)]
    recorder.sync()
    assert [(e.outcome, e.marked_by) for e in recorder.history] == [(Outcome.FAILURE, MONITOR), (Outcome.UNMARKED, None)]
    recorder.verdict(True, "ana", 1)  # the operator disagrees after the monitor judged
    recorder.verdict(True, "ana", 1)  # the same mark again is not a second overrule
    recorder.verdict(False, "ana", 2)  # the operator judges first ...
    connector.events += [Event("verdict", at(8).timestamp(), 2, success=True, score=1.0)]  # ... the monitor differs
    recorder.sync()
    assert len(overrules) == 2

    restarted = RolloutRecorder(Connector(), history=from_status(as_status(recorder.history)),
                                on_overrule=lambda: overrules.append(1))
    restarted.sync()
    assert len(overrules) == 2


def test_an_overrule_from_the_verdict_list_marks_the_judged_rollout_it_names_even_ended() -> None:
    # Rollout 1 judged success and ended; the job reused index 1 for a later rollout.
    history = fold(Begun(1, 3, at(0.0004)), judged(1, True, 5), Ended(at(6)), Begun(1, 3, at(7)), judged(1, True, 9))
    # The page names it as the status shows it: milliseconds.
    changed = apply(history, Overruled(False, "ana", at(10), 1, at(0)))
    assert [(e.outcome, e.marked_by) for e in changed] == [(Outcome.FAILURE, "ana"), (Outcome.SUCCESS, MONITOR)]
    assert changed[0].monitor == history[0].monitor and changed[0].ended_at == at(6) and overruled(changed[0])


@pytest.mark.parametrize("rollout, started", [(1, 3.0), (2, 0.0)], ids=["another start", "another index"])
def test_an_overrule_naming_no_judged_rollout_changes_nothing(rollout: int, started: float) -> None:
    history = fold(Begun(1, 3, at(0)), judged(1, True, 5), Ended(at(6)))
    assert apply(history, Overruled(False, "ana", at(10), rollout, at(started))) is history
    unjudged = fold(Begun(1, 3, at(0)), Marked(True, "bo", at(2)))
    assert apply(unjudged, Overruled(False, "ana", at(10), 1, at(0))) is unjudged  # no monitor verdict to overrule


def test_the_recorder_records_an_overrule_counts_it_and_says_when_there_was_nothing_to_overrule() -> None:
    connector = Connector()
    overrules: list[int] = []
    recorder = RolloutRecorder(connector, clock=lambda: at(9), on_overrule=lambda: overrules.append(1))
    connector.events += [Event("begin", at(0).timestamp(), 1, 2),
                         Event("verdict", at(5).timestamp(), 1, success=True, score=0.8),
                         Event("end", at(6).timestamp())]
    assert recorder.overrule(False, "ana", 1, at(0)) is True  # caught up with the connector first
    assert [(e.outcome, e.marked_by) for e in recorder.history] == [(Outcome.FAILURE, "ana")]
    assert recorder.overrule(False, "ana", 1, at(1)) is False
    assert len(overrules) == 1


def test_a_verdict_event_with_a_score_that_is_not_a_number_records_zero() -> None:
    connector = Connector()
    recorder = RolloutRecorder(connector)
    connector.events += [Event("begin", at(0).timestamp(), 1, 1),
                         Event("verdict", at(1).timestamp(), 1, success=True, score=float("nan"))]
    recorder.sync()
    [entry] = recorder.history
    assert entry.monitor is not None and entry.monitor.score == 0.0


def test_the_history_is_kept_in_the_cells_record_and_no_link_planted_there_is_followed(tmp_path) -> None:  # noqa: ANN001
    import json

    from armnet_node.runner import keep_rollouts

    record = tmp_path / "record"
    record.mkdir()
    target, other = tmp_path / "host-file", tmp_path / "another-host-file"
    target.write_text("host data")
    other.write_text("more host data")
    # What a compromised connector (the directory's owner in a pod) could plant for the agent, root.
    (record / "rollouts.json").symlink_to(target)
    (record / ".rollouts.json.partial").symlink_to(other)
    history = fold(Begun(1, 2, at(0)), judged(1, True, 5), Ended(at(6)))

    keep_rollouts(record, history)

    assert not (record / "rollouts.json").is_symlink()
    assert json.loads((record / "rollouts.json").read_text()) == {"rollouts": as_status(history)}
    assert (target.read_text(), other.read_text()) == ("host data", "more host data")
    keep_rollouts(record, ())  # a job without rollouts: nothing written, nothing removed
    keep_rollouts(None, history)
    assert json.loads((record / "rollouts.json").read_text()) == {"rollouts": as_status(history)}

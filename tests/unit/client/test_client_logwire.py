"""Reading the agent's log messages: subjects, message ids, lenient payloads, status-made lines."""

from __future__ import annotations

from datetime import datetime, timezone

import pytest
from armnet_client.logwire import decode, decode_message, job_subjects, seq_of
from armnet_client.resources import RobotJob
from armnet_client.statusfeed import changes, ended

from .builders import a_robotjob

pytestmark = pytest.mark.unit

STORED = datetime(2026, 11, 24, 10, 0, 0, tzinfo=timezone.utc)  # noqa: UP017


def test_one_jobs_subjects_are_a_wildcard_under_namespace_and_uid() -> None:
    assert job_subjects("team-a", "0f3c") == "logs.team-a.0f3c.>"


@pytest.mark.parametrize("token", ["a.b", "*", ">", "", "a b"])
def test_tokens_that_would_widen_the_subscription_are_refused(token: str) -> None:
    with pytest.raises(ValueError):
        job_subjects(token, "uid")


@pytest.mark.parametrize(("msg_id", "seq"), [("uid:stdout:42", 42), ("uid:stdout:x", None), (None, None)])
def test_the_line_number_comes_from_the_message_id(msg_id: str | None, seq: int | None) -> None:
    assert seq_of(msg_id) == seq


def test_an_output_line_is_the_payload_as_printed_even_when_it_looks_like_json() -> None:
    line = decode("logs.a.u.stdout", b'{"text": "hi"}', msg_id="u:stdout:1", stream_seq=5, stored_at=STORED)

    assert (line.kind, line.text, line.seq, line.stream_seq, line.time) == (
        "stdout", '{"text": "hi"}', 1, 5, STORED)


def test_a_status_message_takes_its_time_from_at() -> None:
    line = decode("logs.a.u.status", b'{"phase": "running", "detail": {}, "at": "2026-11-24T10:00:01Z"}',
                  msg_id="u:status:running", stream_seq=2, stored_at=STORED)

    assert (line.text, line.seq) == ("status: running", None)
    assert line.time == datetime(2026, 11, 24, 10, 0, 1, tzinfo=timezone.utc)  # noqa: UP017


def test_a_plain_payload_with_the_runtime_timestamp_prefix_uses_that_time() -> None:
    line = decode("logs.a.u.stderr", b"2026-11-24T10:00:02.000001Z oops\n", msg_id=None,
                  stream_seq=1, stored_at=STORED)

    assert line.text == "oops"
    assert line.time == datetime(2026, 11, 24, 10, 0, 2, 1, tzinfo=timezone.utc)  # noqa: UP017


def test_a_line_without_any_time_gets_the_time_jetstream_stored_it() -> None:
    line = decode("logs.a.u.stdout", b"plain", msg_id=None, stream_seq=1, stored_at=STORED)

    assert (line.text, line.time) == ("plain", STORED)


def test_a_terminal_status_message_ends_a_follow() -> None:
    done = decode("logs.a.u.status", b'{"phase": "failed"}', msg_id=None, stream_seq=9, stored_at=STORED)
    running = decode("logs.a.u.status", b'{"phase": "running"}', msg_id=None, stream_seq=8, stored_at=STORED)

    assert (done.terminal_phase, done.text) == ("failed", "status: failed")
    assert running.terminal_phase is None


def test_status_feed_reports_phase_progress_and_rollout_changes() -> None:
    before = RobotJob.model_validate(a_robotjob(phase="queued"))
    after = RobotJob.model_validate(a_robotjob(phase="running", progress="grasping",
                                               rollout={"index": 3, "total": 10}))

    assert [(x.kind, x.text) for x in changes(before, after)] == [
        ("status", "status: running"), ("progress", "grasping"), ("progress", "rollout 3/10")]


def test_status_feed_gives_the_tails_then_the_terminal_status_when_the_job_ends() -> None:
    before = RobotJob.model_validate(a_robotjob(phase="running"))
    after = RobotJob.model_validate(a_robotjob(phase="succeeded", result={
        "stdoutTail": "a\nb\n", "stderrTail": "w\n"}))

    lines = changes(before, after)

    assert [(x.kind, x.text) for x in lines] == [
        ("stdout", "a"), ("stdout", "b"), ("stderr", "w"), ("status", "status: succeeded")]
    assert all(x.source == "status" for x in lines)


def test_status_feed_leaves_the_tails_out_when_the_output_was_already_shown() -> None:
    before = RobotJob.model_validate(a_robotjob(phase="running"))
    after = RobotJob.model_validate(a_robotjob(phase="failed", result={"stdoutTail": "a\n"}))

    assert [(x.kind, x.text) for x in changes(before, after, tails=False)] == [("status", "status: failed")]


def test_a_terminal_status_message_says_why_the_job_ended() -> None:
    payload = b'{"phase": "failed", "detail": {"error": "image x not found on this node"}}'
    done = decode("logs.a.u.status", payload, msg_id=None, stream_seq=9, stored_at=STORED)
    plain = decode("logs.a.u.status", b'{"phase": "succeeded", "detail": {"exitCode": 0}}', msg_id=None,
                   stream_seq=9, stored_at=STORED)

    assert (done.text, done.reason) == ("status: failed", "image x not found on this node")
    assert plain.reason is None


def test_status_feed_ends_with_the_terminal_status_and_why_the_job_ended() -> None:
    before = RobotJob.model_validate(a_robotjob(phase="running"))
    after = RobotJob.model_validate(a_robotjob(phase="timeout", finishedAt="2026-11-24T10:01:00Z", result={
        "error": "job exceeded its timeout of 2 s; it stopped within the 3 s grace window"}))

    last = changes(before, after, tails=False)[-1]

    assert (last.text, last.reason) == (
        "status: timeout", "job exceeded its timeout of 2 s; it stopped within the 3 s grace window")
    assert ended(after) == last
    assert ended(after) is not None and ended(after).reason == last.reason  # type: ignore[union-attr]
    assert ended(before) is None


def test_a_batch_message_gives_each_line_with_its_number_and_its_own_timestamp() -> None:
    payload = b"2026-11-24T10:00:02.000001Z one\n2026-11-24T10:00:02.000002Z two\r\nno stamp"
    lines = decode_message("logs.a.u.stderr", payload, stream_seq=9, stored_at=STORED,
                           headers={"Nats-Msg-Id": "u:stderr:4-6", "Armnet-Lines": "3", "Armnet-Seq": "4"})

    assert [(x.kind, x.text, x.seq, x.stream_seq) for x in lines] == [
        ("stderr", "one", 4, 9), ("stderr", "two", 5, 9), ("stderr", "no stamp", 6, 9)]
    assert [x.time for x in lines] == [datetime(2026, 11, 24, 10, 0, 2, 1, tzinfo=timezone.utc),  # noqa: UP017
                                       datetime(2026, 11, 24, 10, 0, 2, 2, tzinfo=timezone.utc),  # noqa: UP017
                                       STORED]


def test_a_message_in_the_single_line_format_is_one_line_numbered_by_its_message_id() -> None:
    (line,) = decode_message("logs.a.u.stdout", b"a {\n} spread out", stream_seq=3, stored_at=STORED,
                             headers={"Nats-Msg-Id": "u:stdout:12"})

    assert (line.text, line.seq, line.stream_seq) == ("a {\n} spread out", 12, 3)


def test_a_status_or_rerun_message_is_never_split_even_with_a_lines_header() -> None:
    headers = {"Armnet-Lines": "2", "Armnet-Seq": "1"}
    (status,) = decode_message("logs.a.u.status", b'{"phase": "running"}', headers=headers, stream_seq=1,
                               stored_at=STORED)
    (rerun,) = decode_message("logs.a.u.rerun", b"\x00\n\x01", headers=headers, stream_seq=2, stored_at=STORED)

    assert status.text == "status: running" and rerun.data == b"\x00\n\x01"

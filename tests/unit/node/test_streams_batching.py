"""The outbox joins output lines that wait together into one message, and never changes a message once handed out."""

from __future__ import annotations

from pathlib import Path

import pytest
from armnet_core.logbatch import split_lines
from armnet_node.stream_outbox import BatchLimits, Outbox, OutMessage

pytestmark = pytest.mark.unit

SUBJECT = "logs.ns.job.stdout"


def line(seq: int, text: str | None = None, subject: str = SUBJECT) -> OutMessage:
    kind = subject.rsplit(".", 1)[-1]
    return OutMessage(subject, (text if text is not None else f"line {seq}").encode(), f"job:{kind}:{seq}", seq)


def status(phase: str) -> OutMessage:
    return OutMessage("logs.ns.job.status", b'{"phase": "' + phase.encode() + b'"}', f"job:status:{phase}")


def an_outbox(tmp_path: Path | None = None, memory: int = 1 << 20, **limits: int) -> Outbox:
    return Outbox(memory_max_bytes=memory, spool_dir=tmp_path, spool_max_bytes=1 << 20, batch=BatchLimits(**limits))


def lines_of(message: OutMessage) -> list[tuple[int | None, str]]:
    headers = {"Armnet-Lines": str(message.lines), "Armnet-Seq": str(message.seq)} if message.lines > 1 else None
    return [(seq, data.decode()) for seq, data in split_lines(message.payload, headers, message.seq)]


def drain(outbox: Outbox, window: int = 512) -> list[OutMessage]:
    sent: list[OutMessage] = []
    while taken := outbox.peek(window):
        sent.extend(taken)
        outbox.remove(len(taken))
    return sent


def test_consecutive_lines_waiting_together_leave_as_one_message_in_order() -> None:
    outbox = an_outbox()
    for seq in range(1, 6):
        outbox.put(line(seq))

    (message,) = outbox.peek(512)

    assert lines_of(message) == [(seq, f"line {seq}") for seq in range(1, 6)]
    assert (message.msg_id, message.seq, message.lines) == ("job:stdout:1-5", 1, 5)
    assert len(outbox) == 5, "what waits is counted in lines"


def test_a_batch_ends_at_its_line_limit_and_its_byte_limit() -> None:
    by_lines = an_outbox(max_lines=3)
    by_bytes = an_outbox(max_bytes=20)  # "line N" is 6 bytes, plus a separator between lines
    for seq in range(1, 8):
        by_lines.put(line(seq))
        by_bytes.put(line(seq))

    assert [m.lines for m in drain(by_lines)] == [3, 3, 1]
    assert [m.lines for m in drain(by_bytes)] == [3, 3, 1]


def test_a_line_larger_than_the_byte_limit_travels_alone_and_the_order_holds() -> None:
    outbox = an_outbox(max_bytes=100)
    for message in (line(1), line(2), line(3, "z" * 500), line(4), line(5)):
        outbox.put(message)

    sent = drain(outbox)

    assert [lines_of(m) for m in sent] == [[(1, "line 1"), (2, "line 2")], [(3, "z" * 500)],
                                           [(4, "line 4"), (5, "line 5")]]
    assert sent[1].msg_id == "job:stdout:3" and sent[1].lines == 1


def test_another_subject_a_status_or_a_gap_in_the_numbers_starts_a_new_message() -> None:
    outbox = an_outbox()
    for message in (line(1), line(2), line(1, subject="logs.ns.job.stderr"), line(3), status("running"),
                    line(4), line(6), line(7)):
        outbox.put(message)

    sent = drain(outbox)

    assert [(m.subject.rsplit(".", 1)[-1], m.msg_id) for m in sent] == [
        ("stdout", "job:stdout:1-2"), ("stderr", "job:stderr:1"), ("stdout", "job:stdout:3"),
        ("status", "job:status:running"), ("stdout", "job:stdout:4"), ("stdout", "job:stdout:6-7")]


def test_a_message_handed_out_is_resent_unchanged_even_when_more_lines_came() -> None:
    outbox = an_outbox()
    for seq in range(1, 4):
        outbox.put(line(seq))
    first = outbox.peek(512)
    for seq in range(4, 7):  # arrive while the first send waits for its ack, which never comes
        outbox.put(line(seq))

    again = outbox.peek(512)

    assert again[0] == first[0] and first[0].msg_id == "job:stdout:1-3"
    assert [m.msg_id for m in again] == ["job:stdout:1-3", "job:stdout:4-6"]


def test_only_as_many_messages_as_asked_are_joined_and_sealed() -> None:
    outbox = an_outbox(max_lines=2)
    for seq in range(1, 10):
        outbox.put(line(seq))

    assert [m.msg_id for m in outbox.peek(2)] == ["job:stdout:1-2", "job:stdout:3-4"]
    outbox.remove(1)
    assert [m.msg_id for m in outbox.peek(3)] == ["job:stdout:3-4", "job:stdout:5-6", "job:stdout:7-8"]


def test_a_window_ends_past_its_byte_bound_but_always_holds_one_message() -> None:
    outbox = an_outbox(max_lines=1)
    for seq in range(1, 6):
        outbox.put(line(seq, "q" * 100))
    size = outbox.peek(1)[0].size

    assert len(outbox.peek(512, max_bytes=2 * size + size // 2)) == 2
    assert len(outbox.peek(512, max_bytes=size // 2)) == 1


def test_lines_kept_in_the_spool_during_an_outage_are_joined_when_they_come_back(tmp_path: Path) -> None:
    outbox = an_outbox(tmp_path, memory=2000)  # a spool load brings back what memory holds
    for seq in range(1, 201):
        assert outbox.put(line(seq))
    assert outbox.spooled > 0

    sent = drain(outbox)

    assert [pair for m in sent for pair in lines_of(m)] == [(seq, f"line {seq}") for seq in range(1, 201)]
    assert len(sent) <= 10 and len(outbox) == 0


def test_discarding_a_joined_message_counts_its_lines_as_dropped() -> None:
    outbox = an_outbox()
    for seq in range(1, 11):
        outbox.put(line(seq))
    outbox.peek(512)

    assert outbox.discard_all() == 10
    assert outbox.dropped == 10

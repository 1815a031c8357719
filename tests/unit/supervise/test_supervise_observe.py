"""Output observation: marker lines become events and result facts; tails stay bounded."""

from __future__ import annotations

import pytest
from armnet_launch.supervise.observe import EventKind, OutputObserver, Stream
from armnet_launch.supervise.supervisor import iter_lines
from armnet_launch.supervise.tail import BoundedTail
from armnet_runtime.markers import format_progress, format_result, format_traceback

pytestmark = pytest.mark.unit

STAMP = "2026-11-21T02:00:00.000001Z "


def test_a_progress_marker_becomes_a_progress_event_with_its_message() -> None:
    observer = OutputObserver()
    event = observer.feed(Stream.STDOUT, STAMP + format_progress("step 3/10"))
    assert (event.kind, event.text) == (EventKind.PROGRESS, "step 3/10")
    assert observer.last_progress == "step 3/10"


def test_a_result_marker_records_the_return_value() -> None:
    observer = OutputObserver()
    observer.feed(Stream.STDOUT, format_result({"positions": [1, 2]}) + "\n")
    assert observer.has_return_value
    assert observer.return_value == {"positions": [1, 2]}


def test_a_result_of_null_still_counts_as_returned() -> None:
    observer = OutputObserver()
    observer.feed(Stream.STDOUT, format_result(None))
    assert observer.has_return_value and observer.return_value is None


def test_a_traceback_marker_records_the_traceback() -> None:
    observer = OutputObserver()
    event = observer.feed(Stream.STDOUT, STAMP + format_traceback("Traceback\nKeyError: 'x'"))
    assert event.kind is EventKind.TRACEBACK
    assert observer.traceback == "Traceback\nKeyError: 'x'"


def test_markers_on_stderr_are_plain_log_lines() -> None:
    observer = OutputObserver()
    event = observer.feed(Stream.STDERR, format_result(1))
    assert event.kind is EventKind.LOG
    assert not observer.has_return_value
    assert observer.stderr_tail.text() == format_result(1) + "\n"


def test_a_malformed_marker_is_a_log_line() -> None:
    observer = OutputObserver()
    event = observer.feed(Stream.STDOUT, "[armnet:result]:json {not json")
    assert event.kind is EventKind.LOG
    assert not observer.has_return_value


def test_ordinary_lines_go_to_the_tail() -> None:
    observer = OutputObserver()
    observer.feed(Stream.STDOUT, "hello\n")
    assert observer.stdout_tail.text() == "hello\n"


def test_the_tail_keeps_the_newest_lines_within_its_cap() -> None:
    tail = BoundedTail(max_chars=10)
    for word in ("aaaa", "bbbb", "cccc"):
        tail.append(word)
    assert tail.text() == "bbbb\ncccc\n"
    assert tail.dropped_lines == 1


def test_a_line_longer_than_the_cap_keeps_its_end() -> None:
    tail = BoundedTail(max_chars=4)
    tail.append("abcdefgh")
    assert tail.text() == "fgh\n"


def test_lines_split_across_chunks_and_utf8_boundaries_are_rejoined() -> None:
    data = "héllo\nwörld\nlast".encode()
    chunks = [data[i : i + 3] for i in range(0, len(data), 3)]
    assert list(iter_lines(iter(chunks))) == ["héllo", "wörld", "last"]

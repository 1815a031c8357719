"""Marker lines: formatting, the 64 KiB traceback cap, parsing with and without timestamps."""

from __future__ import annotations

import io
import threading
from datetime import UTC, datetime

import pytest
from armnet_runtime import markers
from armnet_runtime.markers import (
    PROGRESS_MARKER,
    RERUN_MARKER,
    RESULT_MARKER_JSON,
    TRACEBACK_MARKER_JSON,
    Marker,
    parse_marker_line,
)
from armnet_runtime.streams import TimestampedStream
from hypothesis import given
from hypothesis import strategies as st

pytestmark = pytest.mark.unit

MOMENT = datetime(2026, 1, 2, 3, 4, 5, 123456, tzinfo=UTC)


def test_marker_prefixes_have_the_documented_values() -> None:
    assert PROGRESS_MARKER == "[armnet:progress]"
    assert RESULT_MARKER_JSON == "[armnet:result]:json"
    assert TRACEBACK_MARKER_JSON == "[armnet:traceback]:json"
    assert RERUN_MARKER == "[armnet:rerun]:b64"


@pytest.mark.parametrize(
    "value", [{"success_rate": 1.0, "names": ["a", "é"]}, [1, 2, 3], "text", 0, False, None]
)
def test_result_marker_round_trips(value: object) -> None:
    parsed = parse_marker_line(markers.format_result(value) + "\n")
    assert parsed == Marker("result", value, None)


def test_result_marker_refuses_non_json_values_with_a_clear_error() -> None:
    with pytest.raises(TypeError, match="JSON-serialisable"):
        markers.format_result({"x": object()})
    with pytest.raises(TypeError, match="finite"):
        markers.format_result(float("nan"))


def test_progress_marker_round_trips_and_stays_one_line() -> None:
    line = markers.format_progress("step 1\nstep 2")
    assert "\n" not in line
    assert parse_marker_line(line) == Marker("progress", "step 1 step 2")


def test_traceback_marker_round_trips_multiline_text() -> None:
    text = 'Traceback (most recent call last):\n  File "x.py"\nValueError: "quoted" é\n'
    assert parse_marker_line(markers.format_traceback(text)) == Marker("traceback", text)


def test_traceback_is_capped_at_64_kib_keeping_the_tail() -> None:
    text = "".join(f"frame {i}\n" for i in range(20000)) + "ValueError: the real cause\n"
    parsed = parse_marker_line(markers.format_traceback(text))
    assert parsed is not None
    payload = parsed.payload
    assert len(payload.encode()) <= markers.TRACEBACK_MAX_BYTES
    assert payload.endswith("ValueError: the real cause\n")
    assert payload.startswith("... [armnet: traceback truncated")
    assert "frame 0\n" not in payload


def test_rerun_marker_round_trips_bytes() -> None:
    data = bytes(range(256)) * 3
    assert parse_marker_line(markers.format_rerun(data)) == Marker("rerun", data)


def test_parse_reads_the_timestamp_prefix() -> None:
    line = f"{markers.format_timestamp(MOMENT)} {markers.format_result({'a': 1})}\n"
    assert line.startswith("2026-01-02T03:04:05.123456Z ")
    assert parse_marker_line(line) == Marker("result", {"a": 1}, MOMENT)


@pytest.mark.parametrize(
    "line",
    [
        "hello world",
        "[armnet:progress]x",
        "[armnet:result]:json {not json",
        "[armnet:traceback]:json 42",
        "[armnet:rerun]:b64 !!!",
        " [armnet:progress] leading space",
        "",
    ],
)
def test_non_marker_and_malformed_lines_parse_to_none(line: str) -> None:
    assert parse_marker_line(line) is None


def test_empty_progress_message_is_a_marker() -> None:
    assert parse_marker_line("[armnet:progress]") == Marker("progress", "")


def test_timestamped_stream_prefixes_every_line_with_the_time_it_started() -> None:
    sink = io.StringIO()
    stream = TimestampedStream(sink, clock=lambda: MOMENT)
    stream.write("first\nsecond par")
    stream.write("t\n")
    stream.flush()
    stamp = "2026-01-02T03:04:05.123456Z "
    assert sink.getvalue() == f"{stamp}first\n{stamp}second part\n"


def test_timestamped_stream_flushes_a_partial_line_once_and_continues_it() -> None:
    sink = io.StringIO()
    stream = TimestampedStream(sink, clock=lambda: MOMENT)
    stream.write("Reset the cell workspace, then press Enter. ")
    stream.flush()
    stream.write("ok\nnext\n")
    stamp = "2026-01-02T03:04:05.123456Z "
    assert sink.getvalue() == (
        f"{stamp}Reset the cell workspace, then press Enter. ok\n{stamp}next\n"
    )


def test_records_never_splice_into_a_pending_partial_line() -> None:
    sink = io.StringIO()
    stream = TimestampedStream(sink, clock=lambda: MOMENT)
    stream.write("user text")  # print() writes its text and its newline separately
    stream.write_record(markers.format_rerun(b"\x01\x02"))
    stream.write("\n")
    lines = sink.getvalue().splitlines()
    assert [parse_marker_line(line) for line in lines] == [Marker("rerun", b"\x01\x02", MOMENT), None]
    assert lines[1].endswith(" user text")


def test_concurrent_writers_keep_every_marker_parseable() -> None:
    sink = io.StringIO()
    stream = TimestampedStream(sink)

    def progress(worker: int) -> None:
        for i in range(200):
            stream.write(markers.format_progress(f"{worker}-{i}"))
            stream.write("\n")

    def records() -> None:
        for i in range(200):
            stream.write_record(markers.format_result({"i": i}))

    threads = [threading.Thread(target=records)]
    threads[0].start()
    progress(0)
    threads[0].join()
    parsed = [parse_marker_line(line) for line in sink.getvalue().splitlines()]
    results = [m.payload["i"] for m in parsed if m is not None and m.kind == "result"]
    assert results == list(range(200))
    assert all(m is not None and m.timestamp is not None for m in parsed)
    progress_lines = [m.payload for m in parsed if m is not None and m.kind == "progress"]
    assert progress_lines == [f"0-{i}" for i in range(200)]


def _by_the_pattern(line: str) -> tuple[object, str]:
    match = markers._TIMESTAMP_RE.match(line)
    if match is None:
        return None, line
    try:
        return datetime.fromisoformat(match.group(1).replace("Z", "+00:00")), line[match.end():]
    except ValueError:
        return None, line


@pytest.mark.parametrize("line", [
    "2026-11-24T10:00:00.250000Z hello", "2026-11-24T10:00:00.250000Z ", "2026-11-24T10:00:00.250000Zhello",
    "2026-11-24T10:00:00Z hello", "2026-11-24T10:00:00.25+01:00 hello", "2026-13-24T10:00:00.250000Z bad month",
    "2026-11-24 10:00:00.250000Z no T", "2026-11-24T10:00:00.25000xZ x", "٢٠٢٦-11-24T10:00:00.250000Z arabic digits",
    "+026-11-24T10:00:00.250000Z sign", "2026-11-24T10:00:00,250000Z comma", "plain text", "",
])
def test_the_fixed_width_prefix_is_read_as_the_pattern_reads_it(line: str) -> None:
    assert markers.split_timestamp(line) == _by_the_pattern(line)


@given(st.datetimes(min_value=datetime(1970, 1, 2), max_value=datetime(9998, 1, 1)), st.text(max_size=20))
def test_every_formatted_timestamp_splits_back_off_its_line(moment: datetime, rest: str) -> None:
    utc = moment.replace(tzinfo=UTC)
    assert markers.split_timestamp(f"{markers.format_timestamp(utc)} {rest}") == (utc, rest)

"""Decoding Podman's k8s-file (CRI) container log: one stream, in order, pieces joined."""

from __future__ import annotations

import pytest
from armnet_launch.cri_log import CriStreamDecoder, NotCriLog, parse_record

pytestmark = pytest.mark.unit

TS = b"2026-11-24T20:36:06.564712895+00:00"


def rec(stream: str, tag: str, content: str) -> bytes:
    return TS + f" {stream} {tag} {content}\n".encode()


def test_full_records_are_lines_of_their_stream() -> None:
    decoder = CriStreamDecoder("stdout")
    assert decoder.feed(rec("stdout", "F", "a") + rec("stdout", "F", "b b")) == b"a\nb b\n"


def test_partial_pieces_join_into_one_line_at_the_next_full_record() -> None:
    decoder = CriStreamDecoder("stdout")
    assert decoder.feed(rec("stdout", "P", "ab") + rec("stdout", "P", "cd")) == b""
    assert decoder.feed(rec("stdout", "F", "ef")) == b"abcdef\n"


def test_stderr_records_interleaved_with_stdout_go_to_their_own_stream_each_in_order() -> None:
    data = (rec("stdout", "P", "o1-") + rec("stderr", "F", "e1") + rec("stdout", "F", "end")
            + rec("stderr", "P", "e2-") + rec("stdout", "F", "o2") + rec("stderr", "F", "end"))
    stdout, stderr = CriStreamDecoder("stdout"), CriStreamDecoder("stderr")
    assert stdout.feed(data) == b"o1-end\no2\n"
    assert stderr.feed(data) == b"e1\ne2-end\n"


def test_a_record_torn_between_two_reads_is_decoded_once_complete() -> None:
    whole = rec("stdout", "F", "hello world")
    decoder = CriStreamDecoder("stdout")
    assert decoder.feed(whole[:20]) == b""
    assert decoder.feed(whole[20:-3]) == b""
    assert decoder.feed(whole[-3:]) == b"hello world\n"


def test_a_torn_last_record_at_the_end_of_the_file_is_handed_on_by_finish() -> None:
    decoder = CriStreamDecoder("stdout")
    assert decoder.feed(rec("stdout", "F", "one") + rec("stdout", "F", "two")[:-2]) == b"one\n"
    assert decoder.finish() == b"tw"


def test_output_ending_without_a_newline_is_handed_on_by_finish() -> None:
    decoder = CriStreamDecoder("stdout")
    assert decoder.feed(rec("stdout", "F", "x") + rec("stdout", "P", "tail")) == b"x\n"
    assert decoder.finish() == b"tail"


def test_an_empty_line_is_kept() -> None:
    assert CriStreamDecoder("stderr").feed(TS + b" stderr F \n" + TS + b" stderr F\n") == b"\n\n"


def test_content_keeps_its_spaces_and_bytes() -> None:
    assert CriStreamDecoder("stdout").feed(TS + b" stdout F  two  spaces \xff\n") == b" two  spaces \xff\n"


def test_a_line_in_another_format_is_refused_as_not_a_cri_log() -> None:
    with pytest.raises(NotCriLog):
        parse_record(b'{"log":"hi\\n","stream":"stdout","time":"2026-11-24T20:36:06Z"}')

"""What a followed log missed: table tests of the pure recovery."""

from __future__ import annotations

import pytest
from armnet_launch.log_recovery import DeliveredLines, missed_output

pytestmark = pytest.mark.unit


def delivered(*chunks: bytes) -> DeliveredLines:
    lines = DeliveredLines()
    for chunk in chunks:
        lines.add(chunk)
    return lines


@pytest.mark.parametrize(
    ("log", "chunks", "missed"),
    [
        pytest.param(b"a\nb\nc\n", [b"a\nb\nc\n"], b"", id="complete follow: nothing to add"),
        pytest.param(b"a\nb\nc\n", [b"a\n"], b"b\nc\n", id="follow ended early: the tail"),
        pytest.param(b"a\nb\nc\nd\n", [b"a\n", b"d\n"], b"b\nc\n", id="a gap in the middle"),
        pytest.param(b"a\nb\nc\n", [], b"a\nb\nc\n", id="nothing delivered"),
        pytest.param(b"a\nbravo\nc\n", [b"a\nbr"], b"avo\nc\n", id="a half-delivered line is completed"),
        pytest.param(b"x\nx\nx\n", [b"x\n"], b"x\nx\n", id="repeated lines are counted, not merged"),
        pytest.param(b"a\nb", [b"a\n"], b"b", id="last line without newline stays so"),
        pytest.param(b"a\nbc", [b"a\nb"], b"c", id="completing the last line adds no newline"),
        pytest.param(b"a\nb\n", [b"a\nzz"], b"\nb\n", id="an unplaceable fragment is ended, not merged"),
        pytest.param(b"a\nb\nc\nd\n", [b"a\n", b"9\n", b"c\n"], b"b\nd\n", id="a cut fragment matches nothing, is skipped"),
        pytest.param(b"[armnet:progress] 1\n[armnet:result]:json {}\n", [b"[armnet:progress] 1\n"],
                     b"[armnet:result]:json {}\n", id="the result marker the follow dropped"),
    ],
)
def test_missed_output(log: bytes, chunks: list[bytes], missed: bytes) -> None:
    assert missed_output(log, delivered(*chunks)) == missed


def test_delivered_plus_missed_holds_every_line_once() -> None:
    """Podman skips whole log entries; its chunks may still split lines anywhere."""
    lines = [b"line %d\n" % i for i in range(1000)]
    stream = b"".join(lines[:300] + lines[450:600] + lines[800:990])  # two gaps, and the end missing
    chunks = [stream[i : i + 777] for i in range(0, len(stream), 777)]
    got = stream + missed_output(b"".join(lines), delivered(*chunks))
    assert sorted(got.splitlines()) == sorted(line.rstrip(b"\n") for line in lines)

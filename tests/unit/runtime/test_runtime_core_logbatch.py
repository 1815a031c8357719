"""The log stream's batch format: lines joined and split back exactly; a single-line message stays one line."""

from __future__ import annotations

import pytest
from armnet_core.logbatch import (
    LINES_HEADER,
    SEQ_HEADER,
    batch_headers,
    batch_msg_id,
    join_lines,
    split_lines,
)
from hypothesis import given
from hypothesis import strategies as st

pytestmark = pytest.mark.unit

line_bytes = st.binary(max_size=40).filter(lambda b: b"\n" not in b)


@given(st.lists(line_bytes, min_size=1, max_size=30), st.integers(min_value=0, max_value=10**9))
def test_a_batch_splits_back_into_its_lines_numbered_from_the_first(lines: list[bytes], first: int) -> None:
    got = split_lines(join_lines(lines), batch_headers(first, len(lines)))

    assert got == [(first + i, line) for i, line in enumerate(lines)]


def test_a_message_without_the_lines_header_is_one_line_even_with_newlines_in_it() -> None:
    assert split_lines(b"two\nparts", None, seq=7) == [(7, b"two\nparts")]
    assert split_lines(b"plain", {"Nats-Msg-Id": "job:stdout:3"}, seq=3) == [(3, b"plain")]


def test_a_batch_with_a_malformed_first_number_still_gives_its_lines_unnumbered() -> None:
    assert split_lines(b"a\nb", {LINES_HEADER: "2", SEQ_HEADER: "x"}) == [(None, b"a"), (None, b"b")]


def test_a_batch_names_its_first_and_last_line() -> None:
    assert batch_msg_id("job:stdout:5", 9) == "job:stdout:5-9"
    assert batch_headers(5, 5) == {LINES_HEADER: "5", SEQ_HEADER: "5"}

"""Several output lines of one job in one NATS message: the log stream's batch format. Pure.

The node agent publishes a job's stdout, stderr and progress lines on
``logs.<namespace>.<jobId>.<kind>`` (docs/streams.md). One message per line
costs the sender and every reader a NATS message each, which caps a burst at
a few thousand lines a second; so when lines wait for the sender, consecutive
lines of one kind travel together:

- a message **without** the ``Armnet-Lines`` header holds one line, as
  printed (what every agent sent before batching, and what an agent still
  sends for a line that waited alone);
- a message **with** it holds that many lines joined by ``\\n``, numbered
  from ``Armnet-Seq`` on, in the order printed, all of the subject's kind. A
  line holding a ``\\n`` is never joined, so splitting gives the lines back
  exactly.

The agent (writer) and every reader (the client, tests, benches) use this
module, so the format has one definition. Nothing here raises on a strange
message: a reader shows what it got.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Optional

LINES_HEADER = "Armnet-Lines"
"""How many lines the payload holds; absent: one line."""
SEQ_HEADER = "Armnet-Seq"
"""The number of the first line (its ``seq`` in that container stream); the others follow on."""
SEPARATOR = b"\n"


def batch_headers(first_seq: int, count: int) -> dict[str, str]:
    """The headers that mark a message of ``count`` lines numbered from ``first_seq``."""
    return {LINES_HEADER: str(count), SEQ_HEADER: str(first_seq)}


def batch_msg_id(first_line_id: str, last_seq: int) -> str:
    """``<jobId>:<kind>:<first>-<last>``: the first line's message id, then the last line's number."""
    return f"{first_line_id}-{last_seq}"


def join_lines(lines: Sequence[bytes]) -> bytes:
    """The payload of a batch; none of ``lines`` may hold ``\\n`` (the writer sends such a line alone)."""
    return SEPARATOR.join(lines)


def _int(value: Optional[str]) -> Optional[int]:
    return int(value) if value is not None and value.isdigit() else None


def split_lines(
    payload: bytes, headers: Optional[Mapping[str, str]], seq: Optional[int] = None
) -> list[tuple[Optional[int], bytes]]:
    """``(line number, line)`` for every line of one message, in order.

    ``seq`` is the number a single-line message carries elsewhere (its
    message id); a batch numbers its lines from ``Armnet-Seq``. A batch whose
    header is malformed still gives its lines, unnumbered.
    """
    count = _int((headers or {}).get(LINES_HEADER))
    if count is None:
        return [(seq, payload)]
    first = _int((headers or {}).get(SEQ_HEADER))
    parts = payload.split(SEPARATOR)
    if first is None:
        return [(None, part) for part in parts]
    return [(first + index, part) for index, part in enumerate(parts)]

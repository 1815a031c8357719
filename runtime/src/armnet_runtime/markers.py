"""The marker lines ``armnet-runtime`` prints and the agent parses.

A job talks to the platform through its stdout: one marker per line, each a
fixed prefix, one space, and a payload. Lines may carry the ISO-8601 UTC
timestamp prefix that ``armnet-runtime`` puts on every output line. This module
owns the format in both directions (formatting helpers for the SDK,
:func:`parse_marker_line` for the agent) and never does I/O.

| kind | line | payload |
| --- | --- | --- |
| progress | ``[armnet:progress] <text>`` | the text (one line) |
| result | ``[armnet:result]:json <json>`` | the JSON value returned by ``@main`` |
| traceback | ``[armnet:traceback]:json <json string>`` | the traceback, tail kept, <= 64 KiB |
| rerun | ``[armnet:rerun]:b64 <base64>`` | one Rerun packet (see ``rerun_packet.proto``) |
"""

from __future__ import annotations

import base64
import binascii
import json
import re
from dataclasses import dataclass
from datetime import datetime
from typing import Any, Literal, Optional

from armnet_core.times import micro_time, parse_time

PROGRESS_MARKER = "[armnet:progress]"
RESULT_MARKER_JSON = "[armnet:result]:json"
TRACEBACK_MARKER_JSON = "[armnet:traceback]:json"
RERUN_MARKER = "[armnet:rerun]:b64"

TRACEBACK_MAX_BYTES = 64 * 1024
"""Cap on the traceback payload (UTF-8 bytes); the tail is kept, as the raise site is at the end."""

_TRUNCATION_NOTICE = "... [armnet: traceback truncated, {dropped} bytes dropped; full text in stderr]\n"

MarkerKind = Literal["progress", "result", "traceback", "rerun"]

_TIMESTAMP_RE = re.compile(
    r"^(\d{4}-\d{2}-\d{2}T\d{2}:\d{2}:\d{2}(?:\.\d{1,6})?(?:Z|[+-]\d{2}:\d{2})) "
)


@dataclass(frozen=True)
class Marker:
    """One parsed marker line: its kind, its decoded payload, and its timestamp if the line had one.

    ``payload`` is a ``str`` for progress and traceback, the decoded JSON value
    for result, and ``bytes`` (an encoded Rerun packet) for rerun.
    """

    kind: MarkerKind
    payload: Any
    timestamp: Optional[datetime] = None


def format_timestamp(moment: datetime) -> str:
    """ISO-8601 UTC with microseconds and a ``Z`` suffix: ``2026-01-02T03:04:05.123456Z``."""
    return micro_time(moment)


def split_timestamp(line: str) -> tuple[Optional[datetime], str]:
    """Split the ``armnet-runtime`` timestamp prefix off ``line`` (``None`` when there is none)."""
    if len(line) > 27 and line[26:28] == "Z " and line[19] == "." and line[10] == "T" and line[:26].isascii():
        # The prefix format_timestamp writes, on nearly every line: fixed width, parsed
        # without the regex (which costs more than the rest of a log line's handling).
        try:
            return datetime.fromisoformat(line[:26] + "+00:00"), line[28:]
        except ValueError:
            pass
    match = _TIMESTAMP_RE.match(line)
    moment = parse_time(match.group(1)) if match is not None else None
    if match is None or moment is None:
        return None, line
    return moment, line[match.end():]


def format_progress(message: str) -> str:
    """The progress line for ``message``; newlines become spaces so it stays one line."""
    flat = " ".join(str(message).splitlines())
    return f"{PROGRESS_MARKER} {flat}"


def format_result(value: Any) -> str:
    """The result line for a ``@main`` return value.

    Raises ``TypeError`` naming the offending type when ``value`` is not plain
    JSON (NaN and infinity are refused too: the agent must be able to parse it).
    """
    try:
        payload = json.dumps(value, allow_nan=False, separators=(",", ":"), ensure_ascii=True)
    except (TypeError, ValueError) as exc:
        raise TypeError(
            f"the @main return value must be JSON-serialisable (dict, list, str, number, bool, "
            f"None; finite floats only): {exc}. Convert it, e.g. numpy values with .tolist()."
        ) from exc
    return f"{RESULT_MARKER_JSON} {payload}"


def cap_traceback(text: str, limit: int = TRACEBACK_MAX_BYTES) -> str:
    """Cap ``text`` to ``limit`` UTF-8 bytes, keeping the tail behind a truncation notice."""
    data = text.encode("utf-8", errors="replace")
    if len(data) <= limit:
        return text
    notice = _TRUNCATION_NOTICE.format(dropped=len(data))
    budget = max(0, limit - len(notice.encode()))
    tail = data[len(data) - budget:].decode("utf-8", errors="ignore")
    dropped = len(data) - len(tail.encode("utf-8"))
    return _TRUNCATION_NOTICE.format(dropped=dropped) + tail


def format_traceback(text: str) -> str:
    """The traceback line: the capped traceback as one JSON string."""
    return f"{TRACEBACK_MARKER_JSON} {json.dumps(cap_traceback(text), ensure_ascii=True)}"


def format_rerun(packet: bytes) -> str:
    """The Rerun line for one encoded packet."""
    return f"{RERUN_MARKER} {base64.b64encode(packet).decode('ascii')}"


def _payload_after(body: str, marker: str) -> Optional[str]:
    if body == marker:
        return ""
    if body.startswith(marker + " "):
        return body[len(marker) + 1:]
    return None


def parse_marker_line(line: str) -> Optional[Marker]:
    """Parse one output line into a :class:`Marker`, or ``None`` when it is not a valid marker.

    Accepts the line with or without the timestamp prefix and its trailing
    newline. A line that starts like a marker but whose payload does not decode
    (a customer print that happens to look like one) is ``None`` too: the agent
    must never fail on job output.
    """
    timestamp, body = split_timestamp(line.rstrip("\r\n"))
    text = _payload_after(body, PROGRESS_MARKER)
    if text is not None:
        return Marker("progress", text, timestamp)
    text = _payload_after(body, RESULT_MARKER_JSON)
    if text is not None:
        try:
            return Marker("result", json.loads(text), timestamp)
        except ValueError:
            return None
    text = _payload_after(body, TRACEBACK_MARKER_JSON)
    if text is not None:
        try:
            decoded = json.loads(text)
        except ValueError:
            return None
        return Marker("traceback", decoded, timestamp) if isinstance(decoded, str) else None
    text = _payload_after(body, RERUN_MARKER)
    if text is not None:
        try:
            return Marker("rerun", base64.b64decode(text, validate=True), timestamp)
        except (binascii.Error, ValueError):
            return None
    return None

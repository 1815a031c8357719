"""The job log stream's wire format, read side: subjects, message ids and payloads. Pure.

The node agent publishes each output line of a job on
``logs.<namespace>.<jobId>.<kind>`` (``kind``: stdout, stderr, progress, rerun,
status) into the JetStream stream ``ARMNET_LOGS``, with the message id
``<jobId>:<kind>:<seq>`` (``seq``: the line's number in that container stream)
so that re-published lines are dropped by JetStream's duplicate window.

Payloads (docs/streams.md): stdout, stderr and progress carry the line itself
(UTF-8, usually with the ``armnet-runtime`` timestamp prefix), or several
consecutive lines of that kind (``armnet_core.logbatch``: an ``Armnet-Lines``
header, lines joined by ``\n``, numbered from ``Armnet-Seq``); rerun carries
one raw packet; status is JSON ``{"phase", "detail", "at"}`` (a finished job's
``detail.error`` says why it ended). Output lines are never parsed as JSON: a
customer printing JSON must see it as printed. A line's time is the status's
``at``, else the timestamp prefix, else the time JetStream
stored the message.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any, Literal, Optional, Union

from armnet_core.api import TERMINAL_PHASES
from armnet_core.logbatch import LINES_HEADER, split_lines
from armnet_core.times import parse_time
from armnet_runtime.markers import split_timestamp

KINDS = ("stdout", "stderr", "progress", "rerun", "status")
TEXT_KINDS = frozenset({"stdout", "stderr", "progress"})
"""Kinds whose messages may carry several lines."""

Source = Literal["stream", "status"]


@dataclass(frozen=True)
class LogLine:
    """One line of a job's output as the client saw it.

    ``stream_seq`` is JetStream's sequence (0 for lines synthesized from the
    job's status when NATS is unreachable: ``source == "status"``); the client
    resumes after it, so a line is never delivered twice.
    """

    kind: str
    text: str
    time: Optional[datetime]
    stream_seq: int = 0
    seq: Optional[int] = None
    data: Any = field(default=None, compare=False)
    source: Source = "stream"

    @property
    def terminal_phase(self) -> Optional[str]:
        """The phase if this is the agent's status message for a finished job."""
        if self.kind != "status" or not isinstance(self.data, dict):
            return None
        phase = self.data.get("phase")
        return phase if phase in TERMINAL_PHASES else None

    @property
    def reason(self) -> Optional[str]:
        """Why the job ended, if this is its terminal status and it says (``detail.error``)."""
        if self.terminal_phase is None:
            return None
        detail = self.data.get("detail")
        error = detail.get("error") if isinstance(detail, dict) else None
        return error if isinstance(error, str) and error else None


def job_subjects(namespace: str, job_id: str) -> str:
    """The filter for all of one job's log subjects.

    Namespaces (DNS labels) and UIDs never contain ``.``, ``*`` or ``>``, but
    both come from a server answer, so they are checked rather than trusted.
    """
    for token in (namespace, job_id):
        if not token or any(ch in token for ch in ".*> \t\r\n"):
            raise ValueError(f"not a valid subject token: {token!r}")
    return f"logs.{namespace}.{job_id}.>"


def inbox_prefix(namespace: str) -> str:
    """``_INBOX.<namespace>``: replies to this client's requests (JetStream API, fetches) come here.

    With per-tenant NATS users (the chart's ``nats.deploy.auth``) a tenant may
    subscribe only to its own ``_INBOX.<namespace>.>``; a shared ``_INBOX.>``
    would let one tenant read another's replies. Harmless on an open server.
    """
    job_subjects(namespace, "x")
    return f"_INBOX.{namespace}"


def consumer_name(namespace: str, nonce: str) -> str:
    """A unique, unguessable name for one follow's ephemeral consumer.

    Named, not server-named, so the create request's subject carries the
    filter (``$JS.API.CONSUMER.CREATE.<stream>.<name>.logs.<ns>.>``) and NATS
    permissions can limit a tenant to its own namespace's logs.
    """
    return f"armnet-{namespace}-{nonce}"


def kind_of(subject: str) -> str:
    return subject.rsplit(".", 1)[-1]


def seq_of(msg_id: Optional[str]) -> Optional[int]:
    """The per-stream line number from ``<jobId>:<kind>:<seq>``; ``None`` if absent or malformed."""
    if not msg_id:
        return None
    tail = msg_id.rsplit(":", 1)[-1]
    return int(tail) if tail.isdigit() else None


def _parse_time(value: Any) -> Optional[datetime]:
    return parse_time(value) if isinstance(value, str) else None


def decode(
    subject: str, payload: bytes, *, msg_id: Optional[str], stream_seq: int,
    stored_at: Optional[datetime],
) -> LogLine:
    """One JetStream message as a :class:`LogLine`; never raises on a strange payload."""
    kind = kind_of(subject)
    text = payload.decode("utf-8", errors="replace")
    data: Any = None
    moment: Optional[datetime] = None
    if kind == "status":
        try:
            data = json.loads(text)
        except ValueError:
            data = None
        if isinstance(data, dict):
            moment = _parse_time(data.get("at"))
            phase = data.get("phase")
            text = f"status: {phase}" if isinstance(phase, str) and phase else text
    elif kind == "rerun":
        data = bytes(payload)  # a raw packet: keep the bytes undamaged
    text = text.rstrip("\r\n")
    prefixed, rest = split_timestamp(text)
    if prefixed is not None:
        text = rest
    return LogLine(
        kind=kind, text=text, time=moment or prefixed or stored_at, stream_seq=stream_seq,
        seq=seq_of(msg_id), data=data,
    )


def decode_message(
    subject: str, payload: bytes, *, headers: Optional[dict[str, str]], stream_seq: int,
    stored_at: Optional[datetime],
) -> list[LogLine]:
    """Every line of one JetStream message, in order: one, or a batch's; never raises.

    The lines of a batch share the message's ``stream_seq`` and carry their own ``seq``.
    """
    msg_id = headers.get("Nats-Msg-Id") if headers else None
    kind = kind_of(subject)
    if kind not in TEXT_KINDS or not headers or LINES_HEADER not in headers:
        return [decode(subject, payload, msg_id=msg_id, stream_seq=stream_seq, stored_at=stored_at)]
    lines = []
    for seq, data in split_lines(payload, headers):
        text = data.decode("utf-8", errors="replace").rstrip("\r")
        prefixed, rest = split_timestamp(text)
        lines.append(LogLine(kind, rest, prefixed or stored_at, stream_seq, seq))
    return lines


@dataclass(frozen=True)
class CaughtUp:
    """Marker event: everything stored when following began has been delivered (for ``--tail``)."""


Event = Union[LogLine, CaughtUp]

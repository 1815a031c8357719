"""A job's rollout history (``status.rollouts``): what it becomes given one event. Pure.

The agent sees four kinds of event about a running job's rollouts: the
connector recorded a begin or an end (``ctx.cell.rollout_begin`` /
``rollout_end``) or its completion monitor's verdict, and a cell operator's
verdict arrived from the FMS (``fms.<cell>.outcome``, naming the operator). :func:`apply` folds one event
into the history; the agent writes :func:`as_status` of the result as
``status.rollouts`` (the whole list: a JSON merge patch replaces lists, so
writing the same history twice changes nothing).

The rules, each so that a replayed or late event cannot rewrite the record:

- a begin appends an entry (unmarked); the same begin seen again (same index,
  same time) changes nothing; a begin while the previous rollout is still open
  closes that one at the new begin's time (the job moved on without an end);
- an end closes the open rollout; with none open it changes nothing;
- a verdict naming a rollout marks the latest entry of that index, open or
  just ended (the agent's bridge only lets through a verdict for the rollout
  active when it arrived; the end may be recorded first); a verdict naming no
  rollout marks the open one; with no such entry it changes nothing (a job
  without ``rollout_begin`` has no rollout to record it in). A second verdict
  on one rollout replaces the first: the job reads the latest too.
- an overrule (``Overruled``, from the page's list of verdicts) marks the one entry
  of that index and start the monitor judged, open or ended; it never reaches the job;
- the cell's completion monitor's verdict (``Judged``: the connector records
  one per rollout, when it told the job "complete" or at the rollout's end) is
  kept in the entry's ``monitor`` whatever else happens, and becomes the
  entry's outcome (``markedBy: monitor``) unless a cell operator marked it:
  a person's mark always stands. An entry whose operator's outcome differs
  from its monitor's is an overrule (:func:`overruled`).

At most :data:`MAX_ENTRIES` entries are kept, the newest (a job may run
thousands of rollouts; the CRD's ``maxItems`` says the same number).
"""

from __future__ import annotations

import unicodedata
from collections.abc import Mapping
from dataclasses import dataclass, replace
from datetime import datetime
from enum import StrEnum
from typing import Any

from armnet_core.api import MONITOR_MARKED_BY
from armnet_core.times import parse_time, status_time

#: The newest entries kept in ``status.rollouts`` (the CRD's ``maxItems``).
MAX_ENTRIES = 50
#: An operator's name as recorded (``markedBy``); the FMS's own names are at most 64 characters.
OPERATOR_MAX = 128
COUNT_MAX = 1_000_000_000


class Outcome(StrEnum):
    SUCCESS = "success"
    FAILURE = "failure"
    UNMARKED = "unmarked"


#: ``markedBy`` of an outcome the cell's completion monitor decided.
MONITOR = MONITOR_MARKED_BY


@dataclass(frozen=True)
class MonitorMark:
    """The completion monitor's verdict on one rollout, kept for audit even when an operator overrules it."""

    success: bool
    score: float
    at: datetime
    #: When the newest frame the verdict rests on was scored.
    frame_at: datetime | None = None


@dataclass(frozen=True)
class RolloutEntry:
    index: int
    total: int
    started_at: datetime
    outcome: Outcome = Outcome.UNMARKED
    marked_by: str | None = None
    marked_at: datetime | None = None
    ended_at: datetime | None = None
    #: The job asked for the cell operator's Success/Fail buttons (``rollout_begin(outcome_controls=...)``).
    outcome_controls: bool = True
    monitor: MonitorMark | None = None

    @property
    def open(self) -> bool:
        return self.ended_at is None

    @property
    def marked_by_operator(self) -> bool:
        return self.marked_by is not None and self.marked_by != MONITOR


@dataclass(frozen=True)
class Begun:
    index: int
    total: int
    at: datetime
    outcome_controls: bool = True


@dataclass(frozen=True)
class Ended:
    at: datetime


@dataclass(frozen=True)
class Marked:
    success: bool
    by: str
    at: datetime
    #: The rollout the operator judged (the FMS sends the index it showed); None: the open one.
    rollout: int | None = None


@dataclass(frozen=True)
class Judged:
    """The cell's completion monitor judged ``rollout`` (the connector's ``verdict`` event)."""

    rollout: int
    mark: MonitorMark


@dataclass(frozen=True)
class Overruled:
    """A cell operator's outcome for a rollout the monitor judged, given from the page's list of verdicts.

    It may come after the rollout ended (the job has moved on and is not told): it corrects the
    record, as a person reviewing the monitor's verdicts does. It names the rollout by index and
    start, so a later rollout that reuses the index is never marked by it.
    """

    success: bool
    by: str
    at: datetime
    rollout: int
    started_at: datetime


RolloutChange = Begun | Ended | Marked | Judged | Overruled
History = tuple[RolloutEntry, ...]


def operator_name(name: str) -> str:
    """``name`` as it may be recorded: control and format characters removed, at most 128 characters."""
    cleaned = "".join(c for c in name if unicodedata.category(c)[0] != "C")[:OPERATOR_MAX]
    return cleaned if cleaned != MONITOR else f"{MONITOR} (operator)"  # a person is never taken for the monitor


def apply(history: History, change: RolloutChange, limit: int = MAX_ENTRIES) -> History:
    """The history after ``change`` (the same tuple when it changes nothing)."""
    if isinstance(change, Begun):
        return _begun(history, change, limit)
    if isinstance(change, Ended):
        if history and history[-1].open:
            return (*history[:-1], replace(history[-1], ended_at=change.at))
        return history
    if isinstance(change, Judged):
        return _judged(history, change)
    if isinstance(change, Overruled):
        return _overruled(history, change)
    return _marked(history, change)


def _begun(history: History, change: Begun, limit: int) -> History:
    last = history[-1] if history else None
    if last is not None and last.index == change.index and last.started_at == change.at:
        return history
    if last is not None and last.open:
        history = (*history[:-1], replace(last, ended_at=change.at))
    entry = RolloutEntry(index=_count(change.index), total=_count(change.total), started_at=change.at,
                         outcome_controls=change.outcome_controls)
    return (*history, entry)[-limit:] if limit > 0 else ()


def _target(history: History, rollout: int | None) -> int | None:
    """The position of the entry a verdict for ``rollout`` marks (None: no such entry)."""
    for position in range(len(history) - 1, -1, -1):
        entry = history[position]
        if rollout is None and not entry.open:
            return None
        if rollout is None or entry.index == rollout:
            return position
    return None


def _marked(history: History, change: Marked) -> History:
    position = _target(history, change.rollout)
    if position is None:
        return history
    marked = replace(history[position], outcome=Outcome.SUCCESS if change.success else Outcome.FAILURE,
                     marked_by=operator_name(change.by), marked_at=change.at)
    return (*history[:position], marked, *history[position + 1:])


def _judged(history: History, change: Judged) -> History:
    position = _target(history, change.rollout)
    if position is None:
        return history
    entry = replace(history[position], monitor=change.mark)
    if not entry.marked_by_operator:
        entry = replace(entry, outcome=Outcome.SUCCESS if change.mark.success else Outcome.FAILURE,
                        marked_by=MONITOR, marked_at=change.mark.at)
    return (*history[:position], entry, *history[position + 1:])


def _overruled(history: History, change: Overruled) -> History:
    for position in range(len(history) - 1, -1, -1):
        entry = history[position]
        # At the status's precision (milliseconds): the page names the rollout as the status shows it.
        if entry.index == change.rollout and status_time(entry.started_at) == status_time(change.started_at):
            if entry.monitor is None:
                return history  # nothing to overrule: a verdict on it goes to the job (``Marked``)
            marked = replace(entry, outcome=Outcome.SUCCESS if change.success else Outcome.FAILURE,
                             marked_by=operator_name(change.by), marked_at=change.at)
            return (*history[:position], marked, *history[position + 1:])
    return history


def overruled(entry: RolloutEntry) -> bool:
    """A cell operator's outcome that differs from the monitor's verdict on the same rollout."""
    if entry.monitor is None or not entry.marked_by_operator:
        return False
    return (entry.outcome is Outcome.SUCCESS) != entry.monitor.success


def accepts_verdict(history: History, rollout: int | None) -> bool:
    """Whether a cell operator's verdict for ``rollout`` may reach the job.

    Refused when the rollout it names began with ``outcome_controls=False``: the job
    decides that rollout's outcome itself, and the page shows no buttons for it (a
    forged or stale message must not decide it either). With no history at all (the
    agent has seen no rollout events, e.g. an older connector) the verdict is let
    through as before.
    """
    if not history:
        return True
    position = _target(history, rollout)
    return position is None or history[position].outcome_controls


def _count(value: int) -> int:
    return min(max(int(value), 0), COUNT_MAX)


def as_status(history: History) -> list[dict[str, Any]]:
    """``status.rollouts``: one object per entry, oldest first, absent fields left out."""
    rows = []
    for entry in history:
        row: dict[str, Any] = {"index": entry.index, "total": entry.total, "outcome": entry.outcome.value,
                               "startedAt": status_time(entry.started_at), "outcomeControls": entry.outcome_controls}
        if entry.marked_by is not None:
            row["markedBy"] = entry.marked_by
        if entry.marked_at is not None:
            row["markedAt"] = status_time(entry.marked_at)
        if entry.ended_at is not None:
            row["endedAt"] = status_time(entry.ended_at)
        if entry.monitor is not None:
            row["monitor"] = _monitor_status(entry.monitor)
        rows.append(row)
    return rows


def _monitor_status(mark: MonitorMark) -> dict[str, Any]:
    row: dict[str, Any] = {"outcome": (Outcome.SUCCESS if mark.success else Outcome.FAILURE).value,
                           "score": round(mark.score, 4), "at": status_time(mark.at)}
    if mark.frame_at is not None:
        row["frameAt"] = status_time(mark.frame_at)
    return row


def _monitor_mark(value: Any) -> MonitorMark | None:
    if not isinstance(value, Mapping):
        return None
    outcome, score, at = value.get("outcome"), value.get("score"), _time(value.get("at"))
    if outcome not in (Outcome.SUCCESS.value, Outcome.FAILURE.value) or at is None:
        return None
    if isinstance(score, bool) or not isinstance(score, int | float):
        return None
    return MonitorMark(outcome == Outcome.SUCCESS.value, float(score), at, _time(value.get("frameAt")))


def from_status(value: Any, limit: int = MAX_ENTRIES) -> History:
    """The history a job's ``status.rollouts`` holds (after an agent restart); malformed entries skipped."""
    if not isinstance(value, list):
        return ()
    entries = [entry for entry in map(_entry, value) if entry is not None]
    return tuple(entries[-limit:]) if limit > 0 else ()


def _entry(row: Any) -> RolloutEntry | None:
    if not isinstance(row, Mapping):
        return None
    index, total, started = row.get("index"), row.get("total"), _time(row.get("startedAt"))
    if not (type(index) is int and type(total) is int and started is not None):
        return None
    outcome = row.get("outcome")
    by = row.get("markedBy")
    return RolloutEntry(
        index=_count(index), total=_count(total), started_at=started,
        outcome=Outcome(outcome) if outcome in tuple(Outcome) else Outcome.UNMARKED,
        marked_by=(by if by == MONITOR else operator_name(by)) if isinstance(by, str) else None,
        marked_at=_time(row.get("markedAt")), ended_at=_time(row.get("endedAt")),
        outcome_controls=row.get("outcomeControls") is not False,
        monitor=_monitor_mark(row.get("monitor")),
    )


def _time(value: Any) -> datetime | None:
    return parse_time(value) if isinstance(value, str) else None

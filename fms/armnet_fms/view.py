"""The fleet as the cell operator sees it: rows built from Cells, RobotJobs and pending resets.

Pure: plain dicts in (the API objects as listed), frozen dataclasses and JSON
out, the clock passed in. Never shows what an operator does not need: no job
args, no secrets, no logs, no result tails.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from armnet_core.api import ACTIVE_PHASES, SITE_LABEL
from armnet_core.times import parse_time as core_time

INTERLOCK_CONDITION = "InterlockClear"
#: The latest verdicts the cell view lists (``status.rollouts`` keeps up to 50).
VERDICTS_SHOWN = 5
OUTCOMES = ("success", "failure")


@dataclass(frozen=True)
class Verdict:
    """A cell operator's verdict on one rollout, as the agent recorded it in ``status.rollouts``."""

    index: int
    total: int
    outcome: str  # "success" | "failure"
    by: str
    at: str


@dataclass(frozen=True)
class FalseCondition:
    type: str
    reason: str
    message: str


@dataclass(frozen=True)
class JobSummary:
    namespace: str
    name: str
    uid: str
    phase: str
    progress: str
    rollout_index: int | None
    rollout_total: int | None
    #: The current rollout is still going (the agent's history has not recorded its end).
    rollout_active: bool = False
    #: The current rollout asked for Success/Fail (``rollout_begin(outcome_controls=True)``, the default).
    outcome_controls: bool = True
    #: The latest verdicts, newest first.
    verdicts: tuple[Verdict, ...] = ()

    @property
    def key(self) -> str:
        return f"{self.namespace}/{self.name}"

    @property
    def active_phase(self) -> bool:
        return self.phase in ACTIVE_PHASES


@dataclass(frozen=True)
class PendingReset:
    """A reset the cell's job waits on, as announced on ``fms.<cell>.reset.requested``.

    ``request_id`` names this wait: a confirmation carries it, so a click meant
    for one reset can never confirm another.
    """

    cell: str
    namespace: str
    job_uid: str
    request_id: str
    began_at: float  # when the wait began, by the FMS's clock (heard, less the seconds it had waited)
    deadline: float

    def seconds_left(self, now: float) -> float:
        return max(0.0, self.deadline - now)

    def expired(self, now: float) -> bool:
        return now >= self.deadline


@dataclass(frozen=True)
class CellRow:
    name: str
    site: str
    phase: str
    unschedulable: bool
    false_conditions: tuple[FalseCondition, ...]
    interlock: str  # "clear" | "tripped" | "unknown"
    heartbeat_age_s: float | None
    reset_timeout_s: int
    job: JobSummary | None
    reset: PendingReset | None


def parse_time(value: Any) -> float | None:
    """Epoch seconds of an RFC 3339 timestamp, or None for anything else."""
    moment = core_time(value) if isinstance(value, str) else None
    return None if moment is None else moment.timestamp()


def reset_request_id(job_uid: str, announced_at: str) -> str:
    """The id of one reset wait: the job and when the agent announced it (≤ 128 characters)."""
    return f"{job_uid}@{announced_at}"[:128]


def pending_from_notice(cell: str, notice: Mapping[str, Any], reset_timeout_s: float,
                        now: float) -> PendingReset | None:
    """The pending reset a ``reset.requested`` notice announces, or None if it is malformed.

    The deadline is counted from when the FMS heard it (the agent's clock may
    differ), less the seconds the notice says the wait has lasted (``elapsed``:
    the agent repeats a notice while its wait lasts, and the first one heard may
    be a repeat), so the time shown is never longer than the job really waits.
    """
    namespace, job, at = notice.get("namespace"), notice.get("job"), notice.get("at")
    if not all(isinstance(v, str) and v and len(v) <= 253 for v in (namespace, job, at)):
        return None
    assert isinstance(namespace, str) and isinstance(job, str) and isinstance(at, str)
    request = notice.get("request")  # the agent names the wait; older agents did not
    if not (isinstance(request, str) and 0 < len(request) <= 128):
        request = reset_request_id(job, at)
    began = now - _seconds_waited(notice.get("elapsed"), reset_timeout_s)
    return PendingReset(cell=cell, namespace=namespace, job_uid=job, request_id=request, began_at=began,
                        deadline=began + reset_timeout_s)


def _seconds_waited(elapsed: Any, most: float) -> float:
    """A notice's ``elapsed`` as seconds in [0, most]; 0 for anything but a finite positive number."""
    if type(elapsed) not in (int, float):
        return 0.0
    try:
        seconds = float(elapsed)
    except OverflowError:  # an int past a float's range
        return 0.0
    if not math.isfinite(seconds) or seconds <= 0:
        return 0.0
    return min(seconds, most)


def _int(value: Any) -> int | None:
    return value if type(value) is int else None


def _history(status: Mapping[str, Any]) -> list[Mapping[str, Any]]:
    rows = status.get("rollouts")
    return [row for row in rows if isinstance(row, Mapping)] if isinstance(rows, list) else []


def rollout_active(index: int | None, history: list[Mapping[str, Any]]) -> bool:
    """Whether rollout ``index`` still runs: it began and the agent has not recorded its end.

    An agent that keeps no history (older, or the pod launcher) leaves only
    ``status.rollout``: that rollout counts as active, as before, and the agent
    still drops a verdict for a rollout that has ended.
    """
    if index is None:
        return False
    for row in reversed(history):
        if _int(row.get("index")) == index:
            return not row.get("endedAt")
    return True


def outcome_controls(index: int | None, history: list[Mapping[str, Any]]) -> bool:
    """Whether rollout ``index`` asked for the operator's verdict (True unless the agent recorded it did not)."""
    for row in reversed(history):
        if _int(row.get("index")) == index:
            return row.get("outcomeControls") is not False
    return True


def verdicts(history: list[Mapping[str, Any]], limit: int = VERDICTS_SHOWN) -> tuple[Verdict, ...]:
    """The latest marked rollouts, newest first (malformed rows skipped, texts bounded)."""
    found = []
    for row in reversed(history):
        index, total, outcome = _int(row.get("index")), _int(row.get("total")), row.get("outcome")
        if index is None or outcome not in OUTCOMES:
            continue
        found.append(Verdict(index=index, total=total or 0, outcome=str(outcome),
                             by=str(row.get("markedBy") or "")[:128], at=str(row.get("markedAt") or "")[:40]))
        if len(found) >= limit:
            break
    return tuple(found)


def summarize_job(job: Mapping[str, Any]) -> JobSummary:
    meta, status = job.get("metadata") or {}, job.get("status") or {}
    rollout = status.get("rollout") or {}
    history = _history(status)
    index = _int(rollout.get("index"))
    return JobSummary(
        namespace=str(meta.get("namespace", "")), name=str(meta.get("name", "")),
        uid=str(status.get("jobId") or meta.get("uid", "")), phase=str(status.get("phase", "")),
        progress=str(status.get("progress") or "")[:300],
        rollout_index=index,
        rollout_total=_int(rollout.get("total")),
        rollout_active=rollout_active(index, history),
        outcome_controls=outcome_controls(index, history),
        verdicts=verdicts(history),
    )


def _interlock(conditions: Iterable[Mapping[str, Any]]) -> str:
    for condition in conditions:
        if condition.get("type") == INTERLOCK_CONDITION:
            return {"True": "clear", "False": "tripped"}.get(str(condition.get("status")), "unknown")
    return "unknown"


def build_row(cell: Mapping[str, Any], jobs_by_key: Mapping[str, Mapping[str, Any]],
              pending: PendingReset | None, now: float) -> CellRow:
    meta, spec, status = cell.get("metadata") or {}, cell.get("spec") or {}, cell.get("status") or {}
    conditions = [c for c in status.get("conditions") or [] if isinstance(c, Mapping)]
    heartbeat = parse_time(status.get("lastHeartbeatTime"))
    current = status.get("currentJob")
    job_body = jobs_by_key.get(current) if isinstance(current, str) else None
    job = summarize_job(job_body) if job_body is not None else None
    if job is None or job.phase not in ACTIVE_PHASES:
        pending = None  # a reset can only wait inside a job that runs here
    elif pending is not None and (pending.job_uid != job.uid or pending.expired(now)):
        pending = None
    return CellRow(
        name=str(meta.get("name", "")),
        site=str((meta.get("labels") or {}).get(SITE_LABEL, "")),
        phase=str(status.get("phase") or "Unknown"),
        unschedulable=bool(spec.get("unschedulable", False)),
        false_conditions=tuple(
            FalseCondition(str(c.get("type")), str(c.get("reason", "")), str(c.get("message", ""))[:300])
            for c in conditions if c.get("status") == "False"
        ),
        interlock=_interlock(conditions),
        heartbeat_age_s=max(0.0, now - heartbeat) if heartbeat is not None else None,
        reset_timeout_s=int(spec.get("resetTimeoutSeconds") or 300),
        job=job,
        reset=pending,
    )


def jobs_by_key(jobs: Iterable[Mapping[str, Any]]) -> dict[str, Mapping[str, Any]]:
    """The jobs by ``namespace/name``, the key a Cell's ``status.currentJob`` holds."""
    return {f"{(j.get('metadata') or {}).get('namespace')}/{(j.get('metadata') or {}).get('name')}": j
            for j in jobs}


def current_job_uid(cell: Mapping[str, Any], jobs_by_key: Mapping[str, Mapping[str, Any]]) -> str | None:
    """The uid of the job the cell's ``status.currentJob`` names, if it is among the jobs read."""
    current = (cell.get("status") or {}).get("currentJob")
    job = jobs_by_key.get(current) if isinstance(current, str) else None
    uid = (job.get("metadata") or {}).get("uid") if job is not None else None
    return uid if isinstance(uid, str) else None


def build_fleet(cells: Iterable[Mapping[str, Any]], jobs: Iterable[Mapping[str, Any]],
                pending: Mapping[str, PendingReset], now: float, *, site: str = "",
                query: str = "") -> list[CellRow]:
    """The rows of the cells matching ``site`` (label) and ``query`` (substring of the name), by name."""
    by_key = jobs_by_key(jobs)
    rows = []
    for cell in cells:
        row = build_row(cell, by_key, pending.get(str((cell.get("metadata") or {}).get("name"))), now)
        if (site and row.site != site) or (query and query.lower() not in row.name.lower()):
            continue
        rows.append(row)
    return sorted(rows, key=lambda r: r.name)


def row_json(row: CellRow, now: float) -> dict[str, Any]:
    """What the page renders for one cell (and all it may show)."""
    job = row.job
    return {
        "name": row.name, "site": row.site, "phase": row.phase, "unschedulable": row.unschedulable,
        "falseConditions": [{"type": c.type, "reason": c.reason, "message": c.message}
                            for c in row.false_conditions],
        "interlock": row.interlock,
        "heartbeatAgeS": None if row.heartbeat_age_s is None else round(row.heartbeat_age_s, 1),
        "job": None if job is None else {
            "namespace": job.namespace, "name": job.name, "tenant": job.namespace, "phase": job.phase,
            "progress": job.progress, "rolloutIndex": job.rollout_index, "rolloutTotal": job.rollout_total,
            "active": job.phase in ACTIVE_PHASES, "rolloutActive": job.active_phase and job.rollout_active,
            "outcomeControls": job.outcome_controls,
            "verdicts": [{"index": v.index, "total": v.total, "outcome": v.outcome, "by": v.by, "at": v.at}
                         for v in job.verdicts],
        },
        "reset": None if row.reset is None else {
            "request": row.reset.request_id, "secondsLeft": round(row.reset.seconds_left(now), 1),
        },
    }

"""The fleet as the cell operator sees it: rows built from Cells, RobotJobs and pending resets.

Pure: the API objects as listed in, read part by part with the core models
(``armnet_core.lenient``: a malformed part of a Cell hides only that part, for
this is the page an operator opens in an incident), frozen dataclasses and JSON
out, the clock passed in. Never shows what an operator does not need: no job
args, no secrets, no logs, no result tails.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from armnet_core.api import ACTIVE_PHASES, MONITOR_MARKED_BY, SITE_LABEL, CellConditionType
from armnet_core.lenient import read_leniently
from armnet_core.resources import (
    CellSpec,
    CellStatus,
    Condition,
    Metadata,
    RobotJobStatus,
    RolloutRecord,
)
from armnet_core.times import parse_time as core_time
from armnet_core.times import status_time

#: The latest verdicts the cell view lists (``status.rollouts`` keeps up to 50).
VERDICTS_SHOWN = 5
OUTCOMES = ("success", "failure")
#: A Cell's ``spec.resetTimeoutSeconds`` when its spec cannot be read (the CRD's default).
DEFAULT_RESET_TIMEOUT_S = CellSpec.model_fields["reset_timeout_seconds"].default


@dataclass(frozen=True)
class Verdict:
    """The verdict on one rollout, a cell operator's or the cell's completion monitor's, as the agent
    recorded it in ``status.rollouts``."""

    index: int
    total: int
    outcome: str  # "success" | "failure"
    by: str  # an operator's name, or "monitor"
    at: str
    #: When the rollout began (as the status has it): with ``index``, what an overrule names.
    started_at: str = ""
    #: The monitor's own verdict ("success" | "failure") and score, kept when an operator overruled it.
    monitor: str | None = None
    score: float | None = None

    @property
    def overruled(self) -> bool:
        """An operator's outcome that differs from the monitor's verdict on the same rollout."""
        return self.monitor is not None and self.by != MONITOR_MARKED_BY and self.monitor != self.outcome

    @property
    def request(self) -> str:
        """What an overrule of this verdict names (the action's ``request``)."""
        return f"{self.index}@{self.started_at}"


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
class QueueAtCell:
    """The operator's ``status.queue``: jobs waiting for a cell like this one, and when it frees."""

    waiting_jobs: int
    likely_free: float | None  # epoch seconds; None when no job holds the cell
    latest_free: float | None

    def json(self, now: float) -> dict[str, Any]:
        """Seconds from ``now`` (the FMS's clock), never negative: an overdue job frees the cell any moment."""
        def left(moment: float | None) -> float | None:
            return None if moment is None else round(max(0.0, moment - now), 1)

        return {"waitingJobs": self.waiting_jobs, "likelyFreeInS": left(self.likely_free),
                "latestFreeInS": left(self.latest_free)}


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
    #: The operator's summary of the queue at this cell (None when it has written none).
    queue: QueueAtCell | None = None
    #: A simulated twin that runs pre-flights only (``spec.preflight``).
    preflight: bool = False
    #: When its duty cycle's rest ends (epoch seconds; ``status.dutyCycle.restingUntil``), None: not resting.
    resting_until: float | None = None


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


def _job_parts(job: Mapping[str, Any]) -> tuple[Metadata, RobotJobStatus]:
    """A listed job's metadata and status, read with the core models (a malformed part read as empty)."""
    meta = read_leniently(Metadata, job.get("metadata")) or Metadata()
    status = read_leniently(RobotJobStatus, job.get("status") or {}) or RobotJobStatus()
    return meta, status


def rollout_active(index: int | None, history: Sequence[RolloutRecord]) -> bool:
    """Whether rollout ``index`` still runs: it began and the agent has not recorded its end.

    An agent that keeps no history (older, or the pod launcher) leaves only
    ``status.rollout``: that rollout counts as active, as before, and the agent
    still drops a verdict for a rollout that has ended.
    """
    if index is None:
        return False
    for row in reversed(history):
        if row.index == index:
            return row.ended_at is None
    return True


def outcome_controls(index: int | None, history: Sequence[RolloutRecord]) -> bool:
    """Whether rollout ``index`` asked for the operator's verdict (True unless the agent recorded it did not)."""
    for row in reversed(history):
        if row.index == index:
            return row.outcome_controls
    return True


def verdicts(history: Sequence[RolloutRecord], limit: int = VERDICTS_SHOWN) -> tuple[Verdict, ...]:
    """The latest marked rollouts, newest first (texts bounded)."""
    found = []
    for row in reversed(history):
        if row.outcome not in OUTCOMES:
            continue
        found.append(Verdict(index=row.index, total=row.total, outcome=row.outcome,
                             by=(row.marked_by or "")[:128],
                             at=status_time(row.marked_at) if row.marked_at is not None else "",
                             started_at=status_time(row.started_at),
                             monitor=row.monitor.outcome if row.monitor is not None else None,
                             score=_score(row.monitor.score) if row.monitor is not None else None))
        if len(found) >= limit:
            break
    return tuple(found)


def _score(value: float) -> float | None:
    return round(value, 4) if math.isfinite(value) else None


def summarize_job(job: Mapping[str, Any]) -> JobSummary:
    meta, status = _job_parts(job)
    index = status.rollout.index if status.rollout is not None else None
    return JobSummary(
        namespace=meta.namespace or "", name=meta.name,
        uid=status.job_id or meta.uid or "", phase=status.phase or "",
        progress=(status.progress or "")[:300],
        rollout_index=index,
        rollout_total=status.rollout.total if status.rollout is not None else None,
        rollout_active=rollout_active(index, status.rollouts),
        outcome_controls=outcome_controls(index, status.rollouts),
        verdicts=verdicts(status.rollouts),
    )


def _interlock(conditions: Iterable[Condition]) -> str:
    for condition in conditions:
        if condition.type == CellConditionType.INTERLOCK_CLEAR:
            return {"True": "clear", "False": "tripped"}.get(condition.status, "unknown")
    return "unknown"


def _cell_parts(cell: Mapping[str, Any]) -> tuple[Metadata, CellSpec | None, CellStatus]:
    """A listed Cell's metadata, spec and status, read with the core models (a malformed part read as empty)."""
    meta = read_leniently(Metadata, cell.get("metadata")) or Metadata()
    spec = read_leniently(CellSpec, cell.get("spec"))
    status = read_leniently(CellStatus, cell.get("status") or {}) or CellStatus()
    return meta, spec, status


def build_row(cell: Mapping[str, Any], jobs_by_key: Mapping[str, Mapping[str, Any]],
              pending: PendingReset | None, now: float) -> CellRow:
    meta, spec, status = _cell_parts(cell)
    heartbeat = status.last_heartbeat_time
    job_body = jobs_by_key.get(status.current_job) if status.current_job is not None else None
    job = summarize_job(job_body) if job_body is not None else None
    if job is None or job.phase not in ACTIVE_PHASES:
        pending = None  # a reset can only wait inside a job that runs here
    elif pending is not None and (pending.job_uid != job.uid or pending.expired(now)):
        pending = None
    return CellRow(
        name=meta.name,
        site=meta.labels.get(SITE_LABEL, ""),
        phase=status.phase or "Unknown",
        unschedulable=spec.unschedulable if spec is not None else False,
        false_conditions=tuple(
            FalseCondition(c.type, c.reason or "", (c.message or "")[:300])
            for c in status.conditions if c.status == "False"
        ),
        interlock=_interlock(status.conditions),
        heartbeat_age_s=max(0.0, now - heartbeat.timestamp()) if heartbeat is not None else None,
        reset_timeout_s=spec.reset_timeout_seconds if spec is not None else DEFAULT_RESET_TIMEOUT_S,
        job=job,
        reset=pending,
        queue=None if status.queue is None else QueueAtCell(
            status.queue.waiting_jobs,
            status.queue.likely_free.timestamp() if status.queue.likely_free is not None else None,
            status.queue.latest_free.timestamp() if status.queue.latest_free is not None else None),
        preflight=spec.preflight if spec is not None else False,
        resting_until=(status.duty_cycle.resting_until.timestamp()
                       if status.duty_cycle is not None and status.duty_cycle.resting_until is not None else None),
    )


def jobs_by_key(jobs: Iterable[Mapping[str, Any]]) -> dict[str, Mapping[str, Any]]:
    """The jobs by ``namespace/name``, the key a Cell's ``status.currentJob`` holds."""
    keyed = {}
    for job in jobs:
        meta = read_leniently(Metadata, job.get("metadata")) or Metadata()
        keyed[f"{meta.namespace}/{meta.name}"] = job
    return keyed


def current_job_uid(cell: Mapping[str, Any], jobs_by_key: Mapping[str, Mapping[str, Any]]) -> str | None:
    """The uid of the job the cell's ``status.currentJob`` names, if it is among the jobs read."""
    current = (read_leniently(CellStatus, cell.get("status") or {}) or CellStatus()).current_job
    job = jobs_by_key.get(current) if current is not None else None
    return (read_leniently(Metadata, job.get("metadata")) or Metadata()).uid if job is not None else None


def build_fleet(cells: Iterable[Mapping[str, Any]], jobs: Iterable[Mapping[str, Any]],
                pending: Mapping[str, PendingReset], now: float, *, site: str = "",
                query: str = "") -> list[CellRow]:
    """The rows of the cells matching ``site`` (label) and ``query`` (substring of the name), by name."""
    by_key = jobs_by_key(jobs)
    rows = []
    for cell in cells:
        name = (read_leniently(Metadata, cell.get("metadata")) or Metadata()).name
        row = build_row(cell, by_key, pending.get(name), now)
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
            "verdicts": [{"index": v.index, "total": v.total, "outcome": v.outcome, "by": v.by, "at": v.at,
                          "monitor": v.monitor, "score": v.score, "overruled": v.overruled, "request": v.request}
                         for v in job.verdicts],
        },
        "queue": None if row.queue is None else row.queue.json(now),
        "preflight": row.preflight,
        "restEndsInS": None if row.resting_until is None else round(max(0.0, row.resting_until - now), 1),
        "reset": None if row.reset is None else {
            "request": row.reset.request_id, "secondsLeft": round(row.reset.seconds_left(now), 1),
        },
    }

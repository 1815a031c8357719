"""What the CLI prints: kubectl-like tables, ``-o json|yaml`` documents, exit codes. Pure.

The JSON shapes are an interface (users script them): a job is the SDK's
``Job`` dump plus ``namespace``, ``jobId``, ``queue`` and ``progress``; a
result is the SDK's ``JobResult`` dump; a cell has fixed keys. Tests pin them.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from datetime import datetime, timezone
from typing import Any, Optional

from armnet_core.api import MONITOR_MARKED_BY, ArtifactsPhase, CellPhase, PreflightPhase
from armnet_core.models import Job, JobResult, JobStatus, TerminalStatus
from armnet_core.times import status_time

from .logwire import LogLine
from .mapping import CellView, JobView, QuotaView

EXIT_SUCCEEDED = 0
EXIT_OTHER_TERMINAL = 1
EXIT_NOT_FINISHED = 2


def result_exit_code(status: JobStatus) -> int:
    """``armnet result``'s exit code: 0 succeeded, 1 failed/timeout/cancelled, 2 not finished."""
    if status is JobStatus.SUCCEEDED:
        return EXIT_SUCCEEDED
    if status in TerminalStatus:
        return EXIT_OTHER_TERMINAL
    return EXIT_NOT_FINISHED


def age(moment: Optional[datetime], now: datetime) -> str:
    """kubectl's compact age: ``45s``, ``12m``, ``3h``, ``2d``; ``<unknown>`` without a time."""
    if moment is None:
        return "<unknown>"
    seconds = max(0, int((now - moment).total_seconds()))
    if seconds < 120:
        return f"{seconds}s"
    if seconds < 7200:
        return f"{seconds // 60}m"
    if seconds < 2 * 86400:
        return f"{seconds // 3600}h"
    return f"{seconds // 86400}d"


def table(headers: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """Columns padded to the widest cell with three spaces between, like kubectl."""
    widths = [max([len(h)] + [len(r[i]) for r in rows]) for i, h in enumerate(headers)]
    lines = ["   ".join(cell.ljust(widths[i]) for i, cell in enumerate(row)).rstrip()
             for row in [list(headers), *rows]]
    return "\n".join(lines)


def _queue_note(job: JobView, now: datetime) -> str:
    """``AllCellsBusy #2, likely in 4m, within 12m``: why it waits, its place, its likely and latest start."""
    if job.status is JobStatus.PREEMPTED and job.requeued_as:
        return f"requeued as {job.requeued_as}"
    if job.preflight is not None and job.preflight.phase == PreflightPhase.FAILED.value:
        return f"pre-flight {job.preflight.job} failed"
    if job.status not in (JobStatus.QUEUED, JobStatus.SUBMITTED) or not job.queued_reason:
        return ""
    position = f" #{job.queue_position}" if job.queue_position else ""
    if job.preflight is not None and job.preflight.phase == PreflightPhase.RUNNING.value:
        return f"{job.queued_reason}{position}, pre-flight {job.preflight.job}"
    starts = ""
    if job.estimated_start is not None:
        likely = job.likely_start
        if likely is not None and age(now, likely) != age(now, job.estimated_start):
            starts = f", likely in {age(now, likely)}"
        starts += f", starts within {age(now, job.estimated_start)}"
    return f"{job.queued_reason}{position}{starts}"


def jobs_table(jobs: Sequence[JobView], now: datetime, *, wide: bool = False) -> str:
    headers = ["NAME", "STATUS", "CELL", "EMBODIMENT", "QUEUE", "AGE"]
    if wide:
        headers += ["TASK", "PRIORITY", "IMAGE", "PROGRESS", "OUTPUT"]
    rows = []
    for job in jobs:
        stopping = " (cancelling)" if job.cancel_requested else " (preempting)" if job.preempting else ""
        status = job.status.value + (stopping if job.status not in TerminalStatus else "")
        row = [job.name, status, job.cell or "<none>", job.embodiment, _queue_note(job, now) or "-",
               age(job.created_at, now)]
        if wide:
            rollout = f" [rollout {job.rollout[0]}/{job.rollout[1]}]" if job.rollout else ""
            row += [job.task or "<any>", str(job.priority), job.image,
                    ((job.progress or "") + rollout + verdict_counts(job)).strip() or "-", output_note(job)]
        rows.append(row)
    return table(headers, rows)


def verdict_counts(job: JobView) -> str:
    """`` [marked: 3 success, 1 failure; 1 overruled]`` from the job's rollout history; empty when nothing was marked.

    Overruled: a cell operator's outcome that differs from the cell's completion monitor's verdict.
    """
    success = sum(1 for r in job.rollouts if r.outcome == "success")
    failure = sum(1 for r in job.rollouts if r.outcome == "failure")
    overruled = sum(1 for r in job.rollouts
                    if r.monitor is not None and r.marked_by not in (None, MONITOR_MARKED_BY) and r.monitor.outcome != r.outcome)
    if not (success or failure):
        return ""
    return f" [marked: {success} success, {failure} failure" + (f"; {overruled} overruled]" if overruled else "]")


def output_note(job: JobView) -> str:
    """The OUTPUT column: ``12 files, 3.4 MB`` once stored, else the upload's phase (``-`` before one)."""
    artifacts = job.artifacts
    if artifacts is None or not artifacts.phase:
        return "-"
    if artifacts.phase != ArtifactsPhase.UPLOADED:
        return artifacts.phase
    note = f"{artifacts.files or 0} files, {_size(artifacts.bytes or 0)}"
    return note if artifacts.complete is not False else note + " (incomplete)"


def _size(count: int) -> str:
    """Bytes as a person reads them (decimal units, as S3 consoles show them)."""
    if count < 1000:
        return f"{count} B"
    value = count / 1000
    for unit in ("kB", "MB"):
        if value < 1000:
            return f"{value:.1f} {unit}"
        value /= 1000
    return f"{value:.1f} GB"


def _when(moment: Optional[datetime]) -> Optional[str]:
    return moment.isoformat() if moment else None


def cells_table(cells: Sequence[CellView], now: datetime, *, wide: bool = False) -> str:
    headers = ["NAME", "PHASE", "EMBODIMENT", "TASK", "JOB", "FAILING", "HEARTBEAT"]
    if wide:
        headers += ["WAITING", "FREE-IN", "NODE", "COMPLETION"]
    rows = []
    for cell in cells:
        failing = ",".join(f"{c.type}({c.reason})" if c.reason else c.type
                           for c in cell.false_conditions) or "-"
        row = [cell.name, _cell_phase(cell, now), cell.embodiment, cell.task or "<any>",
               cell.current_job or "-", failing,
               age(cell.last_heartbeat, now) + (" ago" if cell.last_heartbeat else "")]
        if wide:
            monitor = cell.completion
            row += [*_queue_columns(cell, now), cell.node,
                    f"{monitor.scorer}({monitor.camera})" if monitor else "operator"]
        rows.append(row)
    return table(headers, rows)


def _cell_phase(cell: CellView, now: datetime) -> str:
    """The phase, with what it does not say: ``Resting(12m)`` (its rest ends in 12 minutes) and
    ``Ready,Preflight`` for a twin that runs pre-flights only (as ``kubectl`` shows ``Ready,SchedulingDisabled``)."""
    phase = cell.phase
    if phase == CellPhase.RESTING and cell.resting_until is not None and cell.resting_until > now:
        phase += f"({age(now, cell.resting_until)})"
    return phase + ",Preflight" if cell.preflight else phase


def _queue_columns(cell: CellView, now: datetime) -> list[str]:
    """WAITING and FREE-IN (``4m/12m``: its job likely ends in 4 minutes, at the latest in 12), or ``-``."""
    queue = cell.queue
    if queue is None:
        return ["-", "-"]
    likely = queue.likely_free or queue.latest_free
    if likely is None:
        return [str(queue.waiting_jobs), "-"]
    latest = f"/{age(now, queue.latest_free)}" if queue.latest_free is not None else ""
    return [str(queue.waiting_jobs), f"{age(now, likely)}{latest}"]


def _hours(value: float) -> str:
    return f"{value:.1f}h"


def _credits(quota: QuotaView) -> str:
    """``3.5h/40h per Week``: cell-hours used this period of those granted; ``-`` without credits."""
    if quota.credits_cell_hours is None:
        return "-"
    return f"{_hours(quota.period_used_cell_hours)}/{_hours(quota.credits_cell_hours)} per {quota.period}"


def quotas_table(quotas: Sequence[QuotaView], *, wide: bool = False) -> str:
    """``armnet quota``: each quota's share, what its tenant holds, borrows and waits for, and its credits.

    NOTE says why the operator ignores a quota (it then rations nothing), ``-`` while it is in force.
    """
    headers = ["NAME", "TENANT", "EMBODIMENT", "TASK", "NOMINAL", "IN-USE", "BORROWED", "WAITING", "CREDITS", "NOTE"]
    if wide:
        headers += ["COHORT", "BORROW-LIMIT", "WEIGHT", "USAGE"]
    rows = []
    for quota in quotas:
        if quota.problem:
            row = [quota.name, quota.tenant or "?", "?", "?", "-", "-", "-", "-", "-", quota.problem]
            rows.append(row + (["-", "-", "-", "-"] if wide else []))
            continue
        row = [quota.name, quota.tenant, quota.embodiment, quota.task or "<any>", str(quota.nominal),
               str(quota.in_use), str(quota.borrowed), str(quota.waiting), _credits(quota), quota.message or "-"]
        if wide:
            limit = "-" if quota.cohort is None else ("<idle>" if quota.borrowing_limit is None
                                                       else str(quota.borrowing_limit))
            row += [quota.cohort or "-", limit, f"{quota.weight:g}", _hours(quota.decayed_cell_hours)]
        rows.append(row)
    return table(headers, rows)


def quota_document(quota: QuotaView) -> dict[str, Any]:
    """The ``-o json`` shape of one quota (cell-hours rounded to the second's precision)."""
    return {
        "name": quota.name, "tenant": quota.tenant, "embodiment": quota.embodiment or None, "task": quota.task,
        "nominalCells": quota.nominal if not quota.problem else None, "borrowingLimit": quota.borrowing_limit,
        "weight": quota.weight, "cohort": quota.cohort,
        "cellsInUse": quota.in_use, "borrowedCells": quota.borrowed, "waitingJobs": quota.waiting,
        "credits": None if quota.credits_cell_hours is None else {
            "cellHours": quota.credits_cell_hours, "period": quota.period,
            "usedCellHours": round(quota.period_used_cell_hours, 4)},
        "decayedUsageCellHours": round(quota.decayed_cell_hours, 4),
        "message": quota.message, "problem": quota.problem,
    }


def job_document(job: Job, view: JobView) -> dict[str, Any]:
    """The ``-o json`` shape of one job."""
    document = job.model_dump(mode="json", exclude={"dispatched"})
    document.update({
        "namespace": view.namespace,
        "jobId": view.job_id,
        "queue": {"reason": view.queued_reason, "position": view.queue_position,
                  "estimatedStart": _when(view.estimated_start), "likelyStart": _when(view.likely_start)},
        "progress": view.progress,
        "rollout": {"index": view.rollout[0], "total": view.rollout[1]} if view.rollout else None,
        "rollouts": [{"index": r.index, "total": r.total, "outcome": r.outcome, "markedBy": r.marked_by,
                      "markedAt": _when(r.marked_at), "startedAt": _when(r.started_at), "endedAt": _when(r.ended_at),
                      "monitor": r.monitor.model_dump(mode="json", by_alias=True) if r.monitor else None}
                     for r in view.rollouts],
        "cancelRequested": view.cancel_requested,
        "preflight": view.preflight.model_dump(mode="json", by_alias=True, exclude_none=True) if view.preflight else None,
        "artifacts": view.artifacts.model_dump(mode="json", by_alias=True, exclude_none=True) if view.artifacts else None,
    })
    return document


def cell_document(cell: CellView) -> dict[str, Any]:
    return {
        "name": cell.name, "phase": cell.phase, "embodiment": cell.embodiment, "task": cell.task,
        "node": cell.node, "currentJob": cell.current_job, "unschedulable": cell.unschedulable,
        "preflight": cell.preflight,
        "restingUntil": cell.resting_until.isoformat() if cell.resting_until else None,
        "completion": {"scorer": cell.completion.scorer, "camera": cell.completion.camera} if cell.completion else None,
        "queue": cell.queue.model_dump(mode="json", by_alias=True) if cell.queue else None,
        "lastHeartbeatTime": cell.last_heartbeat.isoformat() if cell.last_heartbeat else None,
        "failingConditions": [{"type": c.type, "reason": c.reason, "message": c.message}
                              for c in cell.false_conditions],
    }


def result_document(result: Optional[JobResult], status: JobStatus) -> dict[str, Any]:
    """``armnet result --json``: the ``JobResult`` dump, or ``{"status": <phase>}`` while unfinished."""
    if result is None:
        return {"status": status.value, "finished": False}
    return {**result.model_dump(mode="json"), "finished": True}


def dumps(document: Any, output: str) -> str:
    if output == "yaml":
        import yaml

        return str(yaml.safe_dump(document, sort_keys=False)).rstrip("\n")
    return json.dumps(document, indent=2)


def log_text(line: LogLine, *, timestamps: bool = True) -> str:
    """One printed log line: ``<UTC time> <text>``; stderr lines are marked, status lines bracketed.

    A finished job's status line is followed by why it ended (``[status: failed] <error>``).
    """
    stamp = f"{status_time(line.time)} " if timestamps and line.time is not None else ""
    if line.kind == "stderr":
        return f"{stamp}[stderr] {line.text}"
    if line.kind == "status":
        reason = line.reason
        return f"{stamp}[{line.text}]" + (f" {reason}" if reason else "")
    return f"{stamp}{line.text}"


def progress_text(line: LogLine, rollout: Optional[tuple[int, int]]) -> str:
    """The live progress line: ``[rollout 3/10] <message>``."""
    prefix = f"[rollout {rollout[0]}/{rollout[1]}] " if rollout else ""
    return f"{prefix}{line.text}"


def rollout_of(line: LogLine) -> Optional[tuple[int, int]]:
    """A rollout step a status message carries: ``{"detail": {"rollout": {"index", "total"}}}``."""
    data = line.data
    if not isinstance(data, dict):
        return None
    detail = data.get("detail")
    found = data.get("rollout") or (detail.get("rollout") if isinstance(detail, dict) else None)
    if isinstance(found, dict) and isinstance(found.get("index"), int):
        total = found.get("total")
        return (int(found["index"]), int(total) if isinstance(total, int) else 0)
    return None


def utcnow() -> datetime:
    return datetime.now(timezone.utc)  # noqa: UP017

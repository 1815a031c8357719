"""The RobotJob status writes of the agent, from what happened. Pure.

Each function returns a JSON merge-patch body for the status subresource,
carrying the resourceVersion it was decided on (a 409 means: re-read and decide
again). Text fields are cut to the CRD's limits, keeping the end (where the
error is). Secret values never reach these bodies: they are built from the
job's output and the connector's record only.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any

from armnet_core import JobResult, JobStatus
from armnet_core.times import status_time

TAIL_MAX = 16384
ERROR_MAX = 8192
TRACEBACK_MAX = 65536
PROGRESS_MAX = 4096


@dataclass(frozen=True)
class ConnectorRecord:
    """What the connector saw during the job (its own record, not guessed from the exit code)."""

    trip_reason: str | None = None
    trip_message: str | None = None
    safety_violations: int = 0
    rollout_index: int | None = None
    rollout_total: int | None = None
    #: The connector's safety report (``connector.report.SafetyReport.as_status()``): clamps,
    #: largest requested step, refusals, trips, torque off confirmed, calibration checks.
    safety: Mapping[str, Any] = field(default_factory=dict)
    #: The cell's record of the job (servo trace, video, rollout pictures): per part, what it kept
    #: and dropped (``Connector.cell_record_counts``); empty when the connector kept none.
    cell_record: Mapping[str, Mapping[str, int]] = field(default_factory=dict)


#: The parts of the cell's record a connector counts (``armnet_connector.connector.CELL_RECORD_PARTS``).
CELL_RECORD_PARTS = ("trace_rows", "video_frames", "rollout_pictures")


def cell_record_counts(data: Any) -> dict[str, dict[str, int]]:
    """The counts of a connector sidecar's record line, known parts and non-negative integers only."""
    if not isinstance(data, Mapping):
        return {}
    counts: dict[str, dict[str, int]] = {}
    for part in CELL_RECORD_PARTS:
        entry = data.get(part)
        if isinstance(entry, Mapping):
            counts[part] = {key: value for key in ("kept", "dropped")
                            if type(value := entry.get(key)) is int and value >= 0}
    return counts


def json_safe(value: Any) -> Any:
    """``value`` with every non-finite float replaced by its name as a string.

    The report carries numbers a hostile job chose (a step of ``inf``); JSON has no
    infinity, and a status body the API server cannot parse would lose the result.
    """
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if isinstance(value, Mapping):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    return value


def _keep_end(text: str | None, limit: int) -> str | None:
    if text is None or len(text) <= limit:
        return text
    marker = "[armnet: cut] "
    return marker + text[-(limit - len(marker)):]


def running_patch(resource_version: str, started_at: datetime) -> dict[str, Any]:
    return {
        "metadata": {"resourceVersion": resource_version},
        "status": {"phase": JobStatus.RUNNING.value, "startedAt": status_time(started_at)},
    }


def progress_patch(progress: str | None, rollout: Mapping[str, int] | None,
                   rollouts: list[dict[str, Any]] | None = None) -> dict[str, Any]:
    """No resourceVersion: progress never changes the phase, and the latest value wins.

    ``rollouts`` is the whole rollout history (``rollout_history.as_status``): a merge
    patch replaces the list, so the same history written twice changes nothing.
    """
    status: dict[str, Any] = {}
    if progress is not None:
        status["progress"] = _keep_end(progress, PROGRESS_MAX)
    if rollout:
        status["rollout"] = dict(rollout)
    if rollouts is not None:
        status["rollouts"] = rollouts
    return {"status": status}


def terminal_patch(
    resource_version: str, result: JobResult, record: ConnectorRecord | None = None,
    rollouts: list[dict[str, Any]] | None = None,
) -> dict[str, Any]:
    """The terminal phase, ``finishedAt`` and ``result`` of a finished job (and its final rollout history)."""
    record = record or ConnectorRecord()
    error = result.error
    if record.trip_reason == "safety" and record.trip_message:
        safety = f"safety violation (connector record): {record.trip_message}"
        error = safety if not error else f"{safety}; {error}"
    body: dict[str, Any] = {
        "exitCode": result.exit_code,
        "stdoutTail": _keep_end(result.stdout, TAIL_MAX),
        "stderrTail": _keep_end(result.stderr, TAIL_MAX),
    }
    if result.return_value is not None:
        body["returnValue"] = result.return_value
    if error:
        body["error"] = _keep_end(error, ERROR_MAX)
    if result.traceback:
        body["traceback"] = _keep_end(result.traceback, TRACEBACK_MAX)
    if record.safety:
        body["safety"] = json_safe(record.safety)
    status: dict[str, Any] = {
        "phase": result.status.value,
        "finishedAt": status_time(result.finished_at) if result.finished_at else None,
        "result": {k: v for k, v in body.items() if v is not None},
    }
    if record.rollout_index is not None:
        status["rollout"] = {"index": record.rollout_index, "total": record.rollout_total or 0}
    if rollouts:
        status["rollouts"] = rollouts
    return {"metadata": {"resourceVersion": resource_version}, "status": status}


def end_detail(patch: Mapping[str, Any], *, requeue_on_preemption: bool = True) -> dict[str, Any]:
    """The ``detail`` of the job's terminal status message on its stream, from the terminal patch written.

    The exit code and error as ``status.result`` has them: a client following the
    stream tells the customer why the job ended without reading the RobotJob. A
    preempted run's also carries ``requeue`` (the job's ``spec.requeueOnPreemption``):
    true, the job goes back to the queue and runs again, so the client keeps following it.
    """
    result = patch["status"].get("result") or {}
    detail = {key: result[key] for key in ("exitCode", "error") if result.get(key) is not None}
    if patch["status"].get("phase") == JobStatus.PREEMPTED.value:
        detail["requeue"] = requeue_on_preemption
    return detail


def failed_before_start(resource_version: str, error: str, now: datetime) -> dict[str, Any]:
    """An infrastructure failure or a bad job (missing Secret): ``failed`` with a short error."""
    return {
        "metadata": {"resourceVersion": resource_version},
        "status": {
            "phase": JobStatus.FAILED.value,
            "finishedAt": status_time(now),
            "result": {"error": _keep_end(error, ERROR_MAX)},
        },
    }

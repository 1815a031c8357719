"""Patch bodies for every write the operator makes, built purely from the models.

Each body is a JSON merge patch that carries the observed
``metadata.resourceVersion``: the API server then applies it only if nothing
changed since we looked (409 Conflict otherwise). That precondition is what
makes "claim the Cell first" safe against a second binder, and what stops a
status write from clobbering the agent's. Lists (conditions, finalizers) are
sent whole, which is safe for the same reason. The one exception is adding
the finalizer (``add_finalizer``): a JSON Patch that appends, needing no
resourceVersion and unable to drop anyone else's finalizer.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime, timedelta
from enum import StrEnum
from typing import Any

from armnet_core.api import RELEASE_CELL_FINALIZER
from armnet_core.times import kube_time, micro_time

from .conditions import set_condition
from .duty_cycle import NO_STATE, DutyState
from .model import (
    BoundReason,
    Cell,
    CellPhase,
    CellQueue,
    Job,
    JobConditionType,
    JobPhase,
)
from .preflight import PREFLIGHT_FAILED
from .scheduling import QueueEntry


class Target(StrEnum):
    CELL_STATUS = "cell-status"
    JOB_STATUS = "job-status"
    JOB = "job"
    QUOTA_STATUS = "cellquota-status"


@dataclass(frozen=True)
class Patch:
    target: Target
    name: str
    namespace: str
    body: dict[str, Any]
    operations: tuple[dict[str, Any], ...] = ()
    """RFC 6902 operations, sent as a JSON Patch instead of ``body`` when set."""


def _cell_status(cell: Cell, status: dict[str, Any]) -> Patch:
    body = {"metadata": {"resourceVersion": cell.resource_version}, "status": status}
    return Patch(Target.CELL_STATUS, cell.name, "", body)


def _job_status(job: Job, status: dict[str, Any]) -> Patch:
    body = {"metadata": {"resourceVersion": job.resource_version}, "status": status}
    return Patch(Target.JOB_STATUS, job.name, job.namespace, body)


def _conditions(job: Job) -> list[dict[str, Any]]:
    return [dict(c) for c in job.conditions]


def quota_status(name: str, status: dict[str, Any]) -> Patch:
    """A CellQuota's status, without a resourceVersion: the leading operator is its only writer,
    and the spec (which others change) is not in the patch."""
    return Patch(Target.QUOTA_STATUS, name, "", {"status": status})


def cell_queue(name: str, queue: CellQueue) -> Patch:
    """A Cell's ``status.queue``, without a resourceVersion: the leading operator is its only
    writer, and a merge patch of that one field cannot clobber the agent's heartbeat or conditions."""
    body = {
        "waitingJobs": queue.waiting_jobs,
        "likelyFree": kube_time(queue.likely_free) if queue.likely_free is not None else None,
        "latestFree": kube_time(queue.latest_free) if queue.latest_free is not None else None,
    }
    return Patch(Target.CELL_STATUS, name, "", {"status": {"queue": body}})


def claim_cell(cell: Cell, job: Job, now: datetime) -> Patch:
    status = {"currentJob": job.key, "claimedAt": kube_time(now), "phase": CellPhase.BUSY.value}
    return _cell_status(cell, status)


def release_cell(cell: Cell, phase: CellPhase, duty: DutyState | None = None) -> Patch:
    status = {"currentJob": None, "claimedAt": None, "phase": phase.value, "message": cell.invalid}
    return _cell_status(cell, _with_duty(status, duty))


def set_cell_phase(cell: Cell, phase: CellPhase, duty: DutyState | None = None) -> Patch:
    """The phase, with ``message`` saying why an Invalid cell is never bound (cleared otherwise),
    and the duty cycle's state when it changed (``duty``)."""
    return _cell_status(cell, _with_duty({"phase": phase.value, "message": cell.invalid}, duty))


def _with_duty(status: dict[str, Any], duty: DutyState | None) -> dict[str, Any]:
    if duty is None:
        return status
    if duty == NO_STATE:
        return {**status, "dutyCycle": None}
    return {**status, "dutyCycle": {
        "workingSince": kube_time(duty.working_since) if duty.working_since else None,
        "restingUntil": kube_time(duty.resting_until) if duty.resting_until else None}}


def repair_status(job: Job) -> Patch:
    """Clear the status fields that could not be read; unreadable conditions are dropped."""
    status: dict[str, Any] = {}
    for defect in job.status_defects:
        field = defect.removeprefix("status.")
        if field.startswith("conditions"):
            status["conditions"] = _conditions(job)
        elif field and "." not in field:
            status[field] = None
    return _job_status(job, status)


def mark_reconciled(job: Job, ok: bool, message: str, now: datetime) -> Patch:
    """The ``Reconciled`` condition: False while a pass cannot handle this job (with why)."""
    conditions = _conditions(job)
    reason = "Reconciled" if ok else "ReconcileFailed"
    set_condition(conditions, JobConditionType.RECONCILED, ok, reason, message, now)
    return _job_status(job, {"conditions": conditions})


def bind_job(job: Job, cell: Cell, now: datetime) -> Patch:
    conditions = _conditions(job)
    message = f"bound to cell {cell.name} (node {cell.node_name or 'unknown'})"
    set_condition(conditions, JobConditionType.BOUND, True, BoundReason.CLAIMED_CELL, message, now)
    set_condition(conditions, JobConditionType.QUEUED, False, "Bound", message, now)
    status = {
        "phase": JobPhase.DISPATCHED.value,
        "cellName": cell.name,
        "jobId": job.job_id or job.uid or job.key,
        "queuedReason": None,
        "queuePosition": None,
        "estimatedStart": None,
        "likelyStart": None,
        "conditions": conditions,
    }
    return _job_status(job, status)


def queue_job(job: Job, entry: QueueEntry, now: datetime) -> Patch:
    conditions = _conditions(job)
    set_condition(conditions, JobConditionType.QUEUED, True, entry.reason, entry.message, now)
    status = {
        "phase": JobPhase.QUEUED.value,
        "jobId": job.job_id or job.uid or job.key,
        "queuedReason": entry.reason.value,
        "queuePosition": entry.position,
        "estimatedStart": kube_time(entry.latest_start) if entry.latest_start is not None else None,
        "likelyStart": kube_time(entry.likely_start) if entry.likely_start is not None else None,
        "conditions": conditions,
    }
    if job.arrived_at is None:
        status["arrivedAt"] = micro_time(now)  # once: its place among jobs created in the same second
    return _job_status(job, status)


def requeue_job(job: Job, message: str, now: datetime) -> Patch:
    conditions = _conditions(job)
    set_condition(conditions, JobConditionType.BOUND, False, BoundReason.REQUEUED, message, now)
    set_condition(conditions, JobConditionType.QUEUED, True, BoundReason.REQUEUED, message, now)
    status = {
        "phase": JobPhase.QUEUED.value,
        "cellName": None,
        "queuedReason": BoundReason.REQUEUED.value,
        "estimatedStart": None,
        "likelyStart": None,
        "conditions": conditions,
    }
    return _job_status(job, status)


def finish_job(job: Job, phase: JobPhase, reason: str, error: str | None, now: datetime) -> Patch:
    conditions = _conditions(job)
    set_condition(conditions, JobConditionType.QUEUED, False, reason, error or reason, now)
    status: dict[str, Any] = {
        "phase": phase.value,
        "finishedAt": kube_time(now),
        "queuedReason": None,
        "queuePosition": None,
        "estimatedStart": None,
        "likelyStart": None,
        "conditions": conditions,
    }
    if error is not None:
        status["result"] = {"error": error}
    return _job_status(job, status)


def request_cancel(job: Job, now: datetime) -> Patch:
    conditions = _conditions(job)
    message = "the agent stops the job within the cell's grace period and reports cancelled"
    set_condition(conditions, JobConditionType.CANCEL_REQUESTED, True, "Requested", message, now)
    return _job_status(job, {"conditions": conditions})


def request_preemption(job: Job, for_job: str, message: str, episode_wait: timedelta, now: datetime) -> Patch:
    """``status.preemption``: the node agent stops the run at its next episode boundary (docs/operator.md)."""
    request = {"requestedAt": kube_time(now), "forJob": for_job, "message": message[:1024],
               "episodeWaitSeconds": int(episode_wait.total_seconds())}
    return _job_status(job, {"preemption": request})


def name_requeue(job: Job, name: str) -> Patch:
    """``status.requeuedAs`` on the preempted job: its copy exists (created once, found again after a crash)."""
    return _job_status(job, {"requeuedAs": name})


def start_preflight(job: Job, preflight: dict[str, Any]) -> Patch:
    """``status.preflight`` once the job's pre-flight exists (``preflight.started_status``)."""
    return _job_status(job, {"preflight": preflight})


def conclude_preflight(job: Job, preflight: dict[str, Any], error: str | None, now: datetime) -> Patch:
    """``status.preflight`` with the verdict; a failed pre-flight also fails the job, in the same write."""
    if error is None:
        return _job_status(job, {"preflight": preflight})
    failed = finish_job(job, JobPhase.FAILED, PREFLIGHT_FAILED, error, now)
    failed.body["status"]["preflight"] = preflight
    return failed


def cancel_job(job: Job) -> Patch:
    """``spec.cancel`` on a pre-flight whose job is over. No resourceVersion: a cancel is one-way and the
    patch names nothing else, so it cannot undo anyone's write."""
    return Patch(Target.JOB, job.name, job.namespace, {"spec": {"cancel": True}})


def add_finalizer(job: Job) -> Patch:
    """Add ``RELEASE_CELL_FINALIZER`` with a JSON Patch: no resourceVersion, no clobbering, no duplicate.

    The agent writes the job's status right after its bind, so a merge patch of
    the whole list with a resourceVersion often lost that race for nothing:
    finalizers are not what the agent changed. Here a ``test`` pins only the
    finalizer list as we saw it (absent: ``null``), then ``add`` appends to it
    (``/-``) or creates it. The API server rejects the whole patch (422) if the
    list changed meanwhile, so no one else's finalizer is dropped and ours is
    never added twice; the caller treats that as a conflict and re-reads.
    """
    path = "/metadata/finalizers"
    if job.finalizers:
        test: dict[str, Any] = {"op": "test", "path": path, "value": list(job.finalizers)}
        add: dict[str, Any] = {"op": "add", "path": f"{path}/-", "value": RELEASE_CELL_FINALIZER}
    else:
        test = {"op": "test", "path": path, "value": None}
        add = {"op": "add", "path": path, "value": [RELEASE_CELL_FINALIZER]}
    return Patch(Target.JOB, job.name, job.namespace, {}, (test, add))


def set_finalizer(job: Job, present: bool) -> Patch:
    finalizers = [f for f in job.finalizers if f != RELEASE_CELL_FINALIZER]
    if present:
        finalizers.append(RELEASE_CELL_FINALIZER)
    body = {"metadata": {"resourceVersion": job.resource_version, "finalizers": finalizers}}
    return Patch(Target.JOB, job.name, job.namespace, body)

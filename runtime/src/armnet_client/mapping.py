"""Pure mapping between the SDK's job types and the RobotJob custom resource.

``JobSpec`` fields map one to one onto ``RobotJob.spec`` (camelCase there);
the status phase maps onto ``JobStatus`` and ``status.result`` onto
``JobResult``. ``username`` is never sent: the platform knows the caller from
its Kubernetes identity, so a client-supplied name could only lie. No I/O here.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from datetime import datetime
from typing import Any, Optional

from armnet_core.api import API_VERSION, FOLLOWER_TIMEOUT_ANNOTATION
from armnet_core.models import Job, JobSpec, JobStatus, TerminalStatus
from armnet_core.resources import PreflightStatus
from pydantic import ValidationError

from .resources import Cell, CellQueue, CellQuota, JobArtifacts, RobotJob, RolloutRecord
from .results import ClusterJobResult

_NAME_CHARS = re.compile(r"[^a-z0-9-]+")
_GENERATED_PREFIX_MAX = 40


def robotjob_body(spec: JobSpec, *, namespace: str, name: Optional[str] = None,
                  follower_window_s: Optional[float] = None) -> dict[str, Any]:
    """The RobotJob to create for ``spec``: ``metadata.name`` when given, else a generated name.

    ``follower_window_s``: this client will follow the job and send heartbeats;
    a non-detached job is then cancelled by the agent when they stop for that long.

    Defaults are written out (``timeoutSeconds``, ``detach``...) so what the
    user sees in ``kubectl get -o yaml`` is what they asked for, not a default
    the CRD might change later.
    """
    body: dict[str, Any] = {
        "image": spec.image,
        "embodiment": spec.embodiment,
        "args": dict(spec.args),
        "timeoutSeconds": spec.timeout_seconds,
        "secrets": dict(spec.secrets),
        "detach": spec.detach,
    }
    if spec.task is not None:
        body["task"] = spec.task
    metadata: dict[str, Any] = {"namespace": namespace}
    if name:
        metadata["name"] = name
    else:
        metadata["generateName"] = generated_name_prefix(spec.image)
    metadata.update(follower_metadata(spec.detach, follower_window_s))
    return {"apiVersion": API_VERSION, "kind": "RobotJob", "metadata": metadata, "spec": body}


def follower_metadata(detach: bool, window_s: Optional[float]) -> dict[str, Any]:
    """The annotation that declares a following client (nothing for a detached job or no follower)."""
    if detach or window_s is None:
        return {}
    return {"annotations": {FOLLOWER_TIMEOUT_ANNOTATION: f"{window_s:g}"}}


def generated_name_prefix(image: str) -> str:
    """``ghcr.io/acme/pick-cube:1.2`` -> ``pick-cube-``: the apiserver appends a random suffix."""
    repository = image.split("@", 1)[0].rsplit("/", 1)[-1].split(":", 1)[0]
    slug = _NAME_CHARS.sub("-", repository.lower()).strip("-")[:_GENERATED_PREFIX_MAX].strip("-")
    return f"{slug or 'job'}-"


def spec_from_robotjob(job: RobotJob) -> JobSpec:
    """The ``JobSpec`` a RobotJob was created from (``priority``, ``cancel`` have no SDK field)."""
    s = job.spec
    return JobSpec(
        image=s.image,
        args=dict(s.args),
        embodiment=s.embodiment,
        task=s.task,
        timeout_seconds=s.timeout_seconds,
        secrets=dict(s.secrets),
        detach=s.detach,
    )


def status_of(phase: Optional[str]) -> JobStatus:
    """The ``JobStatus`` of a phase; a job no one has looked at yet (no phase) is ``SUBMITTED``."""
    if not phase:
        return JobStatus.SUBMITTED
    return JobStatus(phase)


def requeue_of(job: RobotJob) -> Optional[str]:
    """The job that runs a preempted ``job`` again: its name; ``""`` while the operator is still
    creating it; None when none comes (not preempted, or its spec or a cancel said no requeue)."""
    if job.status.phase != JobStatus.PREEMPTED.value:
        return None
    if job.status.requeued_as:
        return job.status.requeued_as
    wanted = job.spec.requeue_on_preemption and not job.spec.cancel and job.metadata.deletion_timestamp is None
    return "" if wanted else None


def result_from_robotjob(job: RobotJob) -> Optional[ClusterJobResult]:
    """The ``JobResult`` of a finished RobotJob; ``None`` while it has not finished.

    ``stdout``/``stderr`` are the status tails (the last 16 KiB the agent kept);
    the whole output is in the job's log stream (``Client.logs``).
    """
    status = status_of(job.status.phase)
    if status not in TerminalStatus:
        return None
    found = job.status.result
    return ClusterJobResult(
        status=status,
        exit_code=found.exit_code if found else None,
        stdout=found.stdout_tail if found else "",
        stderr=found.stderr_tail if found else "",
        error=found.error if found else None,
        traceback=found.traceback if found else None,
        return_value=found.return_value if found else None,
        started_at=job.status.started_at,
        finished_at=job.status.finished_at,
        artifacts=artifacts_of(job),
    )


def artifacts_of(job: RobotJob) -> Optional[JobArtifacts]:
    """``status.artifacts``; ``None`` when the agent wrote none (yet)."""
    stored = job.status.artifacts
    return stored if stored is not None and stored.phase else None


def job_from_robotjob(job: RobotJob) -> Job:
    """The SDK's ``Job`` view: ``id`` is the RobotJob's name (what ``get``/``cancel`` take)."""
    created = job.metadata.creation_timestamp
    moments = [m for m in (created, job.status.started_at, job.status.finished_at) if m]
    moments += [c.last_transition_time for c in job.status.conditions if c.last_transition_time]
    fields: dict[str, Any] = {
        "id": job.metadata.name,
        "spec": spec_from_robotjob(job),
        "status": status_of(job.status.phase),
        "cell_id": job.status.cell_name,
        "result": result_from_robotjob(job),
    }
    if created is not None:
        fields["created_at"] = created
    if moments:
        fields["updated_at"] = max(moments)
    return Job(**fields)


@dataclass(frozen=True)
class JobView:
    """What the CLI shows of a RobotJob: the SDK fields plus queue and stream details."""

    name: str
    namespace: str
    job_id: Optional[str]
    status: JobStatus
    embodiment: str
    task: Optional[str]
    priority: int
    cell: Optional[str]
    queued_reason: Optional[str]
    queue_position: Optional[int]
    #: While it waits for busy cells: when it starts at the latest (the operator's ``status.estimatedStart``).
    estimated_start: Optional[datetime]
    progress: Optional[str]
    rollout: Optional[tuple[int, int]]
    cancel_requested: bool
    created_at: Optional[datetime]
    started_at: Optional[datetime]
    finished_at: Optional[datetime]
    image: str
    #: While it waits for busy cells: when it likely starts, from recent runs (``status.likelyStart``).
    likely_start: Optional[datetime] = None
    #: The rollout history the node agent recorded (oldest first, at most 50).
    rollouts: tuple[RolloutRecord, ...] = ()
    #: Where the job's output went (None until the node agent wrote it, after the job).
    artifacts: Optional[JobArtifacts] = None
    #: A preempted job: the job that runs it again (``status.requeuedAs``).
    requeued_as: Optional[str] = None
    #: A running job the operator preempted: it stops at its next episode boundary.
    preempting: bool = False
    #: A job with ``spec.preflight``: its pre-flight on a simulated twin and the verdict (``status.preflight``).
    preflight: Optional[PreflightStatus] = None


def view_of(job: RobotJob) -> JobView:
    rollout = job.status.rollout
    return JobView(
        name=job.metadata.name,
        namespace=job.metadata.namespace or "",
        job_id=job.status.job_id,
        status=status_of(job.status.phase),
        embodiment=job.spec.embodiment,
        task=job.spec.task,
        priority=job.spec.priority,
        cell=job.status.cell_name,
        queued_reason=job.status.queued_reason,
        queue_position=job.status.queue_position,
        estimated_start=job.status.estimated_start,
        likely_start=job.status.likely_start,
        progress=job.status.progress,
        rollout=(rollout.index, rollout.total) if rollout else None,
        cancel_requested=job.spec.cancel,
        created_at=job.metadata.creation_timestamp,
        started_at=job.status.started_at,
        finished_at=job.status.finished_at,
        image=job.spec.image,
        rollouts=tuple(job.status.rollouts),
        artifacts=job.status.artifacts,
        requeued_as=job.status.requeued_as,
        preempting=job.status.preemption is not None,
        preflight=job.status.preflight,
    )


def cancel_patch() -> dict[str, Any]:
    """The merge patch that cancels a job (one-way: the CRD refuses ``cancel: false`` afterwards)."""
    return {"spec": {"cancel": True}}


@dataclass(frozen=True)
class FalseCondition:
    type: str
    reason: Optional[str]
    message: Optional[str]


@dataclass(frozen=True)
class CompletionView:
    """A cell's completion monitor as ``armnet cells -o wide`` shows it: which scorer watches which camera."""

    scorer: str
    camera: str


@dataclass(frozen=True)
class CellView:
    """What ``armnet cells`` shows: phase, holder, the health conditions that fail, heartbeat."""

    name: str
    embodiment: str
    task: Optional[str]
    node: str
    phase: str
    current_job: Optional[str]
    last_heartbeat: Optional[datetime]
    false_conditions: tuple[FalseCondition, ...]
    unschedulable: bool
    completion: Optional[CompletionView] = None
    """The cell's completion monitor, None when only an operator's outcome completes an episode."""
    queue: Optional[CellQueue] = None
    """The operator's summary of the queue at the cell (``status.queue``), None before it wrote one."""
    preflight: bool = False
    """A simulated twin that runs pre-flights only (``spec.preflight``): never an ordinary job."""
    resting_until: Optional[datetime] = None
    """Its duty cycle's rest ends then (``status.dutyCycle.restingUntil``); None: not resting."""


def cell_view_of(cell: Cell) -> CellView:
    """A cell without a phase has never been seen by the operator: shown as ``Unknown``."""
    return CellView(
        name=cell.metadata.name,
        embodiment=cell.spec.embodiment,
        task=cell.spec.task,
        node=cell.spec.node_name,
        phase=cell.status.phase or "Unknown",
        current_job=cell.status.current_job,
        last_heartbeat=cell.status.last_heartbeat_time,
        false_conditions=tuple(
            FalseCondition(c.type, c.reason, c.message)
            for c in cell.status.conditions
            if c.status == "False"
        ),
        unschedulable=cell.spec.unschedulable,
        completion=completion_view_of(cell.spec.completion),
        queue=cell.status.queue,
        preflight=cell.spec.preflight,
        resting_until=cell.status.duty_cycle.resting_until if cell.status.duty_cycle else None,
    )


def completion_view_of(spec: Any) -> Optional[CompletionView]:
    """The scorer and camera of ``spec.completion``; a value of another shape shows as ``?``, never fails the list."""
    if spec is None:
        return None
    if not isinstance(spec, dict):
        return CompletionView(scorer="?", camera="?")

    def text(key: str) -> str:
        value = spec.get(key)
        return value[:63] if isinstance(value, str) and value else "?"

    return CompletionView(scorer=text("scorer"), camera=text("camera"))


@dataclass(frozen=True)
class QuotaView:
    """What ``armnet quota`` shows of one CellQuota: the share, what the tenant holds and waits for, credits.

    ``problem`` is set (and the share left empty) when the object cannot be read as a
    CellQuota: it is still listed, so a tenant sees that a quota exists but rations nothing.
    """

    name: str
    tenant: str
    embodiment: str = ""
    task: Optional[str] = None
    nominal: int = 0
    borrowing_limit: Optional[int] = None
    weight: float = 1.0
    cohort: Optional[str] = None
    in_use: int = 0
    borrowed: int = 0
    waiting: int = 0
    credits_cell_hours: Optional[float] = None
    period: Optional[str] = None
    period_used_cell_hours: float = 0.0
    decayed_cell_hours: float = 0.0
    message: Optional[str] = None
    problem: Optional[str] = None


def quota_view_of(body: Mapping[str, Any]) -> QuotaView:
    """One CellQuota body as ``armnet quota`` shows it; a malformed one is a row with its problem, never an error."""
    meta, spec = body.get("metadata"), body.get("spec")
    meta, spec = (meta if isinstance(meta, Mapping) else {}), (spec if isinstance(spec, Mapping) else {})
    name, tenant = str(meta.get("name") or ""), str(spec.get("namespace") or "")
    try:
        quota = CellQuota.model_validate(body)
    except ValidationError as exc:
        where = "; ".join(f"{'.'.join(map(str, e['loc']))}: {e['msg']}" for e in exc.errors()[:3])
        return QuotaView(name=name, tenant=tenant, problem=f"cannot be read ({where}); the operator ignores it")
    usage = quota.status.usage
    return QuotaView(
        name=quota.metadata.name, tenant=quota.spec.namespace, embodiment=quota.spec.embodiment,
        task=quota.spec.task, nominal=quota.spec.nominal_cells, borrowing_limit=quota.spec.borrowing_limit,
        weight=quota.spec.weight, cohort=quota.spec.cohort, in_use=quota.status.cells_in_use,
        borrowed=quota.status.borrowed_cells, waiting=quota.status.waiting_jobs,
        credits_cell_hours=quota.spec.credits_cell_hours, period=quota.spec.period,
        period_used_cell_hours=(usage.period_cell_seconds if usage else 0.0) / 3600,
        decayed_cell_hours=(usage.decayed_cell_seconds if usage else 0.0) / 3600,
        message=quota.status.message or None,
    )

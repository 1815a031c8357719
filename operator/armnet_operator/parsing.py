"""The boundary: RobotJob and Cell bodies from the API server into frozen models.

Pydantic validates the parts the operator relies on (the CRD schema already
rejected most bad input; this guards against older objects and hand-written
status). Unknown fields are ignored so the agent can add its own.
"""

from __future__ import annotations

from collections.abc import Mapping
from datetime import UTC, datetime
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from .model import Cell, CellConditionType, CellPhase, Job, JobConditionType, JobPhase

_HEALTH_TYPES = frozenset(CellConditionType)


class _Lenient(BaseModel):
    model_config = ConfigDict(extra="ignore", populate_by_name=True)


class _Condition(_Lenient):
    type: str
    status: str = "Unknown"
    last_transition_time: datetime | None = Field(default=None, alias="lastTransitionTime")


class _Meta(_Lenient):
    name: str
    namespace: str = ""
    uid: str = ""
    resource_version: str = Field(default="", alias="resourceVersion")
    creation_timestamp: datetime | None = Field(default=None, alias="creationTimestamp")
    deletion_timestamp: datetime | None = Field(default=None, alias="deletionTimestamp")
    finalizers: list[str] = Field(default_factory=list)


class _JobSpec(_Lenient):
    embodiment: str
    task: str | None = None
    priority: int = 0
    cancel: bool = False
    ttl_seconds_after_finished: int | None = Field(default=None, alias="ttlSecondsAfterFinished")


class _JobStatus(_Lenient):
    phase: JobPhase | None = None
    cell_name: str | None = Field(default=None, alias="cellName")
    job_id: str | None = Field(default=None, alias="jobId")
    queued_reason: str | None = Field(default=None, alias="queuedReason")
    queue_position: int | None = Field(default=None, alias="queuePosition")
    finished_at: datetime | None = Field(default=None, alias="finishedAt")
    conditions: list[_Condition] = Field(default_factory=list)


class _JobBody(_Lenient):
    metadata: _Meta
    spec: _JobSpec
    status: _JobStatus = Field(default_factory=_JobStatus)


class _CellSpec(_Lenient):
    embodiment: str
    task: str | None = None
    node_name: str = Field(default="", alias="nodeName")
    unschedulable: bool = False


class _CellStatus(_Lenient):
    phase: CellPhase | None = None
    current_job: str | None = Field(default=None, alias="currentJob")
    claimed_at: datetime | None = Field(default=None, alias="claimedAt")
    last_heartbeat_time: datetime | None = Field(default=None, alias="lastHeartbeatTime")
    conditions: list[_Condition] = Field(default_factory=list)


class _CellBody(_Lenient):
    metadata: _Meta
    spec: _CellSpec
    status: _CellStatus = Field(default_factory=_CellStatus)


def _true_since(conditions: list[_Condition], type_: str) -> datetime | None:
    for condition in conditions:
        if condition.type == type_ and condition.status == "True":
            return condition.last_transition_time
    return None


def parse_job(body: Mapping[str, Any]) -> Job:
    raw = _JobBody.model_validate(_sections(body))
    meta, spec, status = raw.metadata, raw.spec, raw.status
    return Job(
        namespace=meta.namespace,
        name=meta.name,
        created=meta.creation_timestamp or datetime.now(UTC),
        embodiment=spec.embodiment,
        task=spec.task or None,
        priority=spec.priority,
        uid=meta.uid,
        resource_version=meta.resource_version,
        cancel=spec.cancel,
        deleting=meta.deletion_timestamp is not None,
        finalizers=tuple(meta.finalizers),
        phase=status.phase,
        cell_name=status.cell_name or None,
        job_id=status.job_id,
        queued_reason=status.queued_reason,
        queue_position=status.queue_position,
        bound_at=_true_since(status.conditions, JobConditionType.BOUND),
        queued_at=_true_since(status.conditions, JobConditionType.QUEUED),
        cancel_requested_at=_true_since(status.conditions, JobConditionType.CANCEL_REQUESTED),
        finished_at=status.finished_at,
        ttl_seconds_after_finished=spec.ttl_seconds_after_finished,
        conditions=tuple(_plain((body.get("status") or {}).get("conditions") or [])),
    )


def parse_cell(body: Mapping[str, Any]) -> Cell:
    raw = _CellBody.model_validate(_sections(body))
    meta, spec, status = raw.metadata, raw.spec, raw.status
    failing = tuple(
        sorted(c.type for c in status.conditions if c.type in _HEALTH_TYPES and c.status == "False")
    )
    return Cell(
        name=meta.name,
        embodiment=spec.embodiment,
        task=spec.task or None,
        resource_version=meta.resource_version,
        node_name=spec.node_name,
        unschedulable=spec.unschedulable,
        phase=status.phase,
        current_job=status.current_job or None,
        claimed_at=status.claimed_at,
        last_heartbeat=status.last_heartbeat_time,
        failing_conditions=failing,
    )


def _sections(body: Mapping[str, Any]) -> dict[str, Any]:
    """The parts the models read; ``managedFields`` (large, unused) is skipped, not copied."""
    meta = body.get("metadata") or {}
    return {
        "metadata": {key: _plain(item) for key, item in meta.items() if key != "managedFields"},
        "spec": _plain(body.get("spec") or {}),
        "status": _plain(body.get("status") or {}),
    }


def _plain(value: Any) -> Any:
    """kopf hands out read-only mapping views; pydantic wants plain dicts and lists."""
    if isinstance(value, Mapping):
        return {key: _plain(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(item) for item in value]
    return value

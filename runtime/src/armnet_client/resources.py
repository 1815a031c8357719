"""Pydantic models of the RobotJob and Cell bodies the apiserver returns, and nothing else.

These are the client's boundary with the CRDs in ``crds/``: they accept what the
apiserver sends (camelCase, fields missing while the operator or the agent has
not written them yet, unknown fields ignored) and nothing else leaves this module
unvalidated. The mapping to the SDK's ``Job``/``JobResult`` is in ``mapping``.
"""

from __future__ import annotations

from datetime import datetime
from typing import Any, Optional

from pydantic import BaseModel, ConfigDict, Field


class _Body(BaseModel):
    model_config = ConfigDict(extra="ignore", populate_by_name=True, frozen=True)


class Metadata(_Body):
    name: str = ""
    namespace: Optional[str] = None
    uid: Optional[str] = None
    resource_version: Optional[str] = Field(default=None, alias="resourceVersion")
    creation_timestamp: Optional[datetime] = Field(default=None, alias="creationTimestamp")
    deletion_timestamp: Optional[datetime] = Field(default=None, alias="deletionTimestamp")


class Condition(_Body):
    type: str
    status: str
    reason: Optional[str] = None
    message: Optional[str] = None
    last_transition_time: Optional[datetime] = Field(default=None, alias="lastTransitionTime")


class RobotJobSpec(_Body):
    image: str
    embodiment: str
    args: dict[str, Any] = Field(default_factory=dict)
    task: Optional[str] = None
    timeout_seconds: int = Field(default=120, alias="timeoutSeconds")
    secrets: dict[str, str] = Field(default_factory=dict)
    detach: bool = False
    priority: int = 0
    cancel: bool = False
    ttl_seconds_after_finished: Optional[int] = Field(default=None, alias="ttlSecondsAfterFinished")


class Rollout(_Body):
    index: int = 0
    total: int = 0


class MonitorVerdict(_Body):
    """The cell's completion monitor's verdict on one rollout, kept even when an operator overruled it."""

    outcome: str = "failure"  # success | failure
    score: float = 0.0
    at: Optional[datetime] = None
    frame_at: Optional[datetime] = Field(default=None, alias="frameAt")


class RolloutRecord(_Body):
    """One rollout as the node agent recorded it (``status.rollouts``): begin, end, the operator's verdict."""

    index: int = 0
    total: int = 0
    outcome: str = "unmarked"  # success | failure | unmarked
    marked_by: Optional[str] = Field(default=None, alias="markedBy")
    marked_at: Optional[datetime] = Field(default=None, alias="markedAt")
    started_at: Optional[datetime] = Field(default=None, alias="startedAt")
    ended_at: Optional[datetime] = Field(default=None, alias="endedAt")
    monitor: Optional[MonitorVerdict] = None


class RobotJobResult(_Body):
    exit_code: Optional[int] = Field(default=None, alias="exitCode")
    return_value: Any = Field(default=None, alias="returnValue")
    error: Optional[str] = None
    traceback: Optional[str] = None
    stdout_tail: str = Field(default="", alias="stdoutTail")
    stderr_tail: str = Field(default="", alias="stderrTail")


class JobArtifacts(_Body):
    """Where the job's output directory went (``status.artifacts``, written by the node agent after the job)."""

    phase: Optional[str] = None  # Uploading | Uploaded | Retrying | Failed | Discarded
    location: Optional[str] = None
    manifest: Optional[str] = None
    files: Optional[int] = None
    bytes: Optional[int] = None
    complete: Optional[bool] = None
    left_out: Optional[int] = Field(default=None, alias="leftOut")
    message: Optional[str] = None


class RobotJobStatus(_Body):
    phase: Optional[str] = None
    job_id: Optional[str] = Field(default=None, alias="jobId")
    cell_name: Optional[str] = Field(default=None, alias="cellName")
    queued_reason: Optional[str] = Field(default=None, alias="queuedReason")
    queue_position: Optional[int] = Field(default=None, alias="queuePosition")
    estimated_start: Optional[datetime] = Field(default=None, alias="estimatedStart")
    started_at: Optional[datetime] = Field(default=None, alias="startedAt")
    finished_at: Optional[datetime] = Field(default=None, alias="finishedAt")
    progress: Optional[str] = None
    rollout: Optional[Rollout] = None
    rollouts: list[RolloutRecord] = Field(default_factory=list)
    result: Optional[RobotJobResult] = None
    artifacts: Optional[JobArtifacts] = None
    conditions: list[Condition] = Field(default_factory=list)


class RobotJob(_Body):
    metadata: Metadata
    spec: RobotJobSpec
    status: RobotJobStatus = Field(default_factory=RobotJobStatus)


class CellSpec(_Body):
    embodiment: str
    node_name: str = Field(default="", alias="nodeName")
    task: Optional[str] = None
    unschedulable: bool = False
    simulated: bool = False
    completion: Any = None
    """The completion monitor's configuration as written (read leniently: only its scorer and camera are shown)."""


class CellStatus(_Body):
    phase: Optional[str] = None
    current_job: Optional[str] = Field(default=None, alias="currentJob")
    claimed_at: Optional[datetime] = Field(default=None, alias="claimedAt")
    last_heartbeat_time: Optional[datetime] = Field(default=None, alias="lastHeartbeatTime")
    conditions: list[Condition] = Field(default_factory=list)


class Cell(_Body):
    metadata: Metadata
    spec: CellSpec
    status: CellStatus = Field(default_factory=CellStatus)

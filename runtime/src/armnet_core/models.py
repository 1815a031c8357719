"""Wire models shared by the SDK, the agent and the operator.

This module owns the shapes of a job (``JobSpec``, ``Job``), its lifecycle
(``JobStatus``, ``TerminalStatus``) and its outcome (``JobResult``). It holds
pure data and validation only: no I/O, no imports beyond pydantic.
"""

from __future__ import annotations

import uuid
from datetime import datetime, timezone
from enum import Enum
from typing import Any, Optional

from pydantic import BaseModel, Field

Embodiment = str
"""A robot embodiment name, e.g. ``lerobot/so-101``."""

Task = str
"""A task name a cell is configured for."""

SO101_EMBODIMENT = "lerobot/so-101"
BIMANUAL_SO101_EMBODIMENT = "lerobot/bimanual_so101"


def _new_job_id() -> str:
    """A fresh, unique job id (random UUID4 hex: no coordination needed between clients)."""
    return uuid.uuid4().hex


def _utcnow() -> datetime:
    return datetime.now(timezone.utc)  # noqa: UP017 - the SDK supports Python 3.10


class JobStatus(str, Enum):  # noqa: UP042 - str() stays the documented JobStatus.RUNNING, not a StrEnum's running
    """Job lifecycle states: submitted → queued/dispatched → running → a terminal state."""

    SUBMITTED = "submitted"
    QUEUED = "queued"
    DISPATCHED = "dispatched"
    RUNNING = "running"
    SUCCEEDED = "succeeded"
    FAILED = "failed"
    TIMEOUT = "timeout"
    CANCELLED = "cancelled"
    PREEMPTED = "preempted"


TerminalStatus = frozenset(
    {JobStatus.SUCCEEDED, JobStatus.FAILED, JobStatus.TIMEOUT, JobStatus.CANCELLED, JobStatus.PREEMPTED}
)
"""The statuses a job never leaves (a preempted job's requeue is a new job: ``status.requeuedAs``)."""


class JobSpec(BaseModel):
    """What a client supplies to create a job (mirrors ``RobotJob.spec``)."""

    image: str = Field(..., description="Container image reference, e.g. `my-image:latest`.")
    args: dict[str, Any] = Field(
        default_factory=dict,
        description="Keyword arguments exposed to @main as `ctx.args` (JSON in `ARMNET_ARGS`).",
    )
    embodiment: Embodiment = Field(..., description="Required robot embodiment.")
    task: Optional[Task] = Field(
        default=None, description="Optional task; when set only cells of that task run the job."
    )
    timeout_seconds: int = Field(default=120, ge=1, description="Wall-clock cap on execution.")
    secrets: dict[str, str] = Field(
        default_factory=dict,
        description="Environment variable name -> secret name in the job's namespace.",
    )
    detach: bool = Field(
        default=False,
        description="If true, the job keeps running after the client disconnects.",
    )
    username: Optional[str] = Field(
        default=None, description="Authenticated username, set by the platform."
    )


class RemoteExecutionError(RuntimeError):
    """Raised by :meth:`JobResult.raise_for_status` for a result that is not ``SUCCEEDED``.

    Its message is ``str(result)`` so an unhandled raise shows status, error and
    traceback; ``result`` keeps the structured value.
    """

    def __init__(self, result: JobResult) -> None:
        self.result = result
        super().__init__(str(result))


class JobResult(BaseModel):
    """The terminal outcome of a job: status, exit code, output, error or traceback, return value."""

    status: JobStatus = Field(..., description="One of the terminal statuses.")
    exit_code: Optional[int] = Field(default=None, description="Container exit code.")
    stdout: str = Field(default="", description="Captured container stdout.")
    stderr: str = Field(default="", description="Captured container stderr.")
    error: Optional[str] = Field(
        default=None, description="Platform-side reason the user code did not complete."
    )
    traceback: Optional[str] = Field(
        default=None, description="Traceback of @main (from the traceback marker), capped at 64 KiB."
    )
    return_value: Optional[Any] = Field(
        default=None, description="Value returned by @main (from the result marker)."
    )
    started_at: Optional[datetime] = None
    finished_at: Optional[datetime] = None

    def raise_for_status(self) -> None:
        """Raise :class:`RemoteExecutionError` unless the job succeeded; a no-op otherwise."""
        if self.status != JobStatus.SUCCEEDED:
            raise RemoteExecutionError(self)

    def __str__(self) -> str:
        """One readable block: status line, then return value, error and indented traceback."""
        head = f"JobResult(status={self.status.value}"
        if self.exit_code is not None:
            head += f", exit_code={self.exit_code}"
        lines = [head + ")"]
        if self.return_value is not None:
            lines.append(f"  return_value: {self.return_value!r}")
        if self.error:
            lines.append(f"  error: {self.error}")
        if self.traceback:
            lines.append("  traceback (from @main):")
            lines.extend(f"    {line}" for line in self.traceback.splitlines())
        return "\n".join(lines)


class Job(BaseModel):
    """The platform's view of a job: its spec plus id, status, timestamps, cell and result."""

    id: str = Field(default_factory=_new_job_id)
    spec: JobSpec
    status: JobStatus = JobStatus.SUBMITTED
    created_at: datetime = Field(default_factory=_utcnow)
    updated_at: datetime = Field(default_factory=_utcnow)
    cell_id: Optional[str] = Field(
        default=None, description="ID of the cell that picked up the job, set on dispatch."
    )
    result: Optional[JobResult] = None
    dispatched: Optional[bool] = Field(
        default=None,
        description="Only on a create response: True if dispatched at once, False if queued.",
    )

    def is_terminal(self) -> bool:
        return self.status in TerminalStatus

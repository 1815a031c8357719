"""The operator's view of RobotJobs and Cells: plain frozen data, no I/O.

Everything the decision modules (``scheduling``, ``lifecycle``) reason about is
defined here, together with the condition types and reasons the operator owns;
the phases and the Cell's health condition types are the API's (``armnet_core.api``,
re-exported here). Parsing from Kubernetes bodies lives in ``parsing``; this module must never
import kopf, kubernetes or the agent.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from enum import StrEnum
from typing import Any

from armnet_core.api import ACTIVE_PHASES as _ACTIVE
from armnet_core.api import (
    RELEASE_CELL_FINALIZER,
    ArtifactsPhase,
    CellConditionType,
    CellPhase,
    JobPhase,
    PreflightPhase,
)
from armnet_core.api import TERMINAL_PHASES as _TERMINAL

from .duty_cycle import NO_STATE, DutyCycle, DutyState

#: A job not queued yet sorts after every queued job created in the same second (``Job.queue_order``).
_NOT_ARRIVED = datetime.max.replace(tzinfo=UTC)

TERMINAL_PHASES = frozenset(JobPhase(phase) for phase in _TERMINAL)
ACTIVE_PHASES = frozenset(JobPhase(phase) for phase in _ACTIVE)


class JobConditionType(StrEnum):
    """Condition types the operator owns on a RobotJob (the agent owns the others)."""

    QUEUED = "Queued"
    BOUND = "Bound"
    CANCEL_REQUESTED = "CancelRequested"
    RECONCILED = "Reconciled"


class QueuedReason(StrEnum):
    """Why a job waits: each names what a person can do about it."""

    NO_CELL_FOR_EMBODIMENT = "NoCellForEmbodiment"
    NO_CELL_FOR_EMBODIMENT_AND_TASK = "NoCellForEmbodimentAndTask"
    ALL_CELLS_BUSY = "AllCellsBusy"
    ALL_CELLS_UNAVAILABLE = "AllCellsUnavailable"
    WAITING_FOR_CELL_RELEASE = "WaitingForCellRelease"
    QUOTA_EXHAUSTED = "QuotaExhausted"
    PREFLIGHT_RUNNING = "PreflightRunning"
    """The job's pre-flight runs (or waits) on a simulated twin; it joins the queue once that passes."""


class BoundReason(StrEnum):
    CLAIMED_CELL = "ClaimedCell"
    REQUEUED = "Requeued"


@dataclass(frozen=True)
class Job:
    """A RobotJob as the scheduler sees it. ``key`` is ``namespace/name``."""

    namespace: str
    name: str
    created: datetime
    embodiment: str
    task: str | None = None
    priority: int = 0
    uid: str = ""
    resource_version: str = ""
    cancel: bool = False
    deleting: bool = False
    finalizers: tuple[str, ...] = (RELEASE_CELL_FINALIZER,)
    phase: JobPhase | None = None
    cell_name: str | None = None
    job_id: str | None = None
    queued_reason: str | None = None
    queue_position: int | None = None
    bound_at: datetime | None = None
    queued_at: datetime | None = None
    cancel_requested_at: datetime | None = None
    finished_at: datetime | None = None
    ttl_seconds_after_finished: int | None = None
    timeout_seconds: int = 120
    started_at: datetime | None = None
    estimated_start: datetime | None = None
    """``status.estimatedStart`` as last written (``estimate``: the latest start while it waits)."""
    likely_start: datetime | None = None
    """``status.likelyStart`` as last written (``estimate``: the likely start, from recent runs)."""
    conditions: tuple[Mapping[str, Any], ...] = ()
    spec_problem: str | None = None
    """Why this job can never start (args too deep or too large, an unreadable spec): it fails."""
    status_defects: tuple[str, ...] = ()
    """Status fields that could not be read (e.g. ``status.finishedAt``): read as absent, then repaired."""
    requeue_on_preemption: bool = True
    preemption_requested_at: datetime | None = None
    """``status.preemption.requestedAt``: the operator asked the agent to stop the run at an episode boundary."""
    requeued_as: str | None = None
    """``status.requeuedAs``: the job created to run this preempted one again."""
    preflight_seconds: int | None = None
    """``spec.preflight.seconds``: the job runs on a simulated twin first (``preflight``); None: no pre-flight."""
    preflight_phase: PreflightPhase | None = None
    """``status.preflight.phase``: the verdict on the job's pre-flight so far (None: not started)."""
    preflight_job: str | None = None
    """``status.preflight.job``: the name of the job's pre-flight RobotJob (same namespace)."""
    preflight_for: str | None = None
    """The ``armnet.io/preflight-for`` annotation: this job is the pre-flight of the job with this uid."""
    arrived_at: datetime | None = None
    """``status.arrivedAt``: when the operator first queued the job, in microseconds (``queue_order``)."""
    artifacts_location: str | None = None
    """``status.artifacts.location``: where the node agent stored the job's outputs (``s3://bucket/ns/uid/``)."""
    artifacts_phase: str | None = None
    """``status.artifacts.phase``: ``Uploading`` or ``Retrying`` while the agent is still at it."""
    keep_artifacts: bool = False
    """The ``armnet.io/keep-artifacts: "true"`` annotation: its outputs outlive the job's TTL."""

    @property
    def queue_order(self) -> tuple[int, datetime, datetime, str, str]:
        """Where the job waits: by priority, then creation, then arrival, then namespace and name.

        A creation time has whole seconds, so jobs created in one second tie on it. Broken
        by namespace and name, a job arriving late in that second went ahead of peers
        already numbered and moved each of them one place back: during a burst most
        positions were rewritten again and again. ``arrived_at`` (stamped with the job's
        first queue position) keeps the order of arrival instead: a job not stamped yet
        arrived after every stamped one, and positions once written stay.
        """
        return (-self.priority, self.created, self.arrived_at or _NOT_ARRIVED, self.namespace, self.name)

    @property
    def uploading(self) -> bool:
        """The node agent is still storing the job's outputs (``status.artifacts``)."""
        return self.artifacts_phase in (ArtifactsPhase.UPLOADING.value, ArtifactsPhase.RETRYING.value)

    @property
    def has_finalizer(self) -> bool:
        return RELEASE_CELL_FINALIZER in self.finalizers

    @property
    def key(self) -> str:
        return f"{self.namespace}/{self.name}"

    @property
    def preempting(self) -> bool:
        """Asked to stop at its next episode boundary: its cell is on its way back."""
        return self.preemption_requested_at is not None

    @property
    def is_preflight(self) -> bool:
        """A pre-flight run: bound only to pre-flight cells, rationed by no CellQuota, never preempted."""
        return self.preflight_for is not None

    @property
    def awaits_preflight(self) -> bool:
        """Asked for a pre-flight that has not passed (yet): never bound to a cell meanwhile."""
        return (self.preflight_seconds is not None and not self.is_preflight
                and self.preflight_phase is not PreflightPhase.PASSED)

    @property
    def terminal(self) -> bool:
        return self.phase in TERMINAL_PHASES

    @property
    def active(self) -> bool:
        return self.phase in ACTIVE_PHASES

    @property
    def waiting(self) -> bool:
        """True while the job may still be bound: not yet dispatched and not being stopped."""
        return (
            self.phase in (None, JobPhase.SUBMITTED, JobPhase.QUEUED)
            and not self.cancel
            and not self.deleting
            and self.spec_problem is None
        )


@dataclass(frozen=True)
class Arm:
    """One arm of a Cell (``spec.robot`` or an entry of ``spec.arms``), as far as checks need it."""

    name: str
    port: str | None = None
    robot_id: str | None = None
    calibration_dir: str | None = None
    safety_limit: float | None = None


@dataclass(frozen=True)
class CellQueue:
    """``status.queue``: the jobs waiting for a cell like this one, and when it frees (likely, at the latest).

    Written by the operator for the cell operator's page (``estimate.cell_queues``); no
    scheduling decision reads it back.
    """

    waiting_jobs: int = 0
    likely_free: datetime | None = None
    latest_free: datetime | None = None


@dataclass(frozen=True)
class Cell:
    """A Cell as the scheduler sees it. ``current_job`` is the claim (``namespace/name``)."""

    name: str
    embodiment: str
    task: str | None = None
    resource_version: str = ""
    node_name: str = ""
    unschedulable: bool = False
    grace_period: timedelta = timedelta(seconds=10)
    phase: CellPhase | None = None
    current_job: str | None = None
    claimed_at: datetime | None = None
    last_heartbeat: datetime | None = None
    failing_conditions: tuple[str, ...] = ()
    uid: str = ""
    created: datetime | None = None
    arms: tuple[Arm, ...] = ()
    message: str | None = None
    """``status.message`` as last written by the operator (why the cell is Invalid)."""
    invalid: str | None = None
    """Why the cell must never be bound (set by ``cell_checks``, not read from the API)."""
    spec_problem: str | None = None
    """A spec field that could not be read (named): the cell is Invalid until it is fixed."""
    queue: CellQueue = CellQueue()
    """``status.queue`` as last written (empty when absent)."""
    preflight: bool = False
    """``spec.preflight``: a simulated twin that runs pre-flights only (and no ordinary job)."""
    duty_cycle: DutyCycle | None = None
    """``spec.dutyCycle``: rest R minutes every H hours (``duty_cycle``)."""
    duty: DutyState = NO_STATE
    """``status.dutyCycle`` as last written."""


@dataclass(frozen=True)
class Timing:
    """The clocks of the lifecycle: why each exists is in docs/operator.md."""

    heartbeat_timeout: timedelta = timedelta(seconds=30)
    claim_grace: timedelta = timedelta(seconds=10)
    lost_grace: timedelta = timedelta(seconds=60)
    cancel_force_after: timedelta = timedelta(seconds=60)
    default_ttl: timedelta | None = timedelta(hours=24)
    episode_wait: timedelta = timedelta(seconds=120)
    """How long a preempted job may run on to its next episode boundary before its grace window opens."""
    outputs_store: bool = False
    """The operator removes a finished job's stored outputs with it at its TTL (``artifact_removal``):
    the TTL delete then waits for the node agent's upload to begin and to settle."""


def job_key(namespace: str, name: str) -> str:
    return f"{namespace}/{name}"


def split_key(key: str) -> tuple[str, str]:
    namespace, _, name = key.partition("/")
    return namespace, name


__all__ = [
    "ACTIVE_PHASES",
    "TERMINAL_PHASES",
    "Arm",
    "BoundReason",
    "Cell",
    "CellConditionType",
    "CellQueue",
    "CellPhase",
    "Job",
    "JobConditionType",
    "JobPhase",
    "PreflightPhase",
    "QueuedReason",
    "Timing",
    "job_key",
    "split_key",
]

"""The RobotJob, Cell and CellQuota as the API server stores them: one set of models for every reader.

The operator, the node agent and the customer's client all read these objects. Each
validates them with these models, the part it acts on, rather than declaring models of
its own (copies drift: a default here, a required field there), and turns them into its
own frozen dataclasses inside
(``armnet_operator.parsing``, ``armnet_node.model``, ``armnet_client.mapping``).

The models accept what the API server sends: camelCase aliases, fields the operator or
the agent has not written yet, unknown fields ignored (the CRDs in ``crds/`` grow), a
timestamp without a zone read as UTC (naive and aware times cannot be compared).
``tests/unit/architecture/test_api_models.py`` keeps their fields in step with the CRDs.
"""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Annotated, Any, Literal, Optional

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, model_validator


def _aware(value: datetime) -> datetime:
    return value if value.tzinfo is not None else value.replace(tzinfo=UTC)


#: A time as the API server writes it (RFC 3339); without a zone, UTC.
Timestamp = Annotated[datetime, AfterValidator(_aware)]


class Wire(BaseModel):
    """The base of every model here: aliases or field names, unknown fields ignored, frozen."""

    model_config = ConfigDict(extra="ignore", populate_by_name=True, frozen=True)


class Metadata(Wire):
    name: str = ""
    namespace: Optional[str] = None
    uid: Optional[str] = None
    resource_version: Optional[str] = Field(default=None, alias="resourceVersion")
    creation_timestamp: Optional[Timestamp] = Field(default=None, alias="creationTimestamp")
    deletion_timestamp: Optional[Timestamp] = Field(default=None, alias="deletionTimestamp")
    finalizers: list[str] = Field(default_factory=list)
    labels: dict[str, str] = Field(default_factory=dict)
    annotations: dict[str, str] = Field(default_factory=dict)


class Condition(Wire):
    type: str
    status: Literal["True", "False", "Unknown"]
    reason: Optional[str] = None
    message: Optional[str] = None
    last_transition_time: Optional[Timestamp] = Field(default=None, alias="lastTransitionTime")


# -- RobotJob --------------------------------------------------------------------------------


class PreflightSpec(Wire):
    """``spec.preflight``: run the job on a simulated twin of its embodiment (a Cell with ``spec.preflight``)
    for at most ``seconds`` first; only a pre-flight that passes lets it join the queue for a real cell."""

    seconds: int = Field(ge=1, le=3600)


class RobotJobSpec(Wire):
    image: str
    embodiment: str
    args: dict[str, Any] = Field(default_factory=dict)
    task: Optional[str] = None
    timeout_seconds: int = Field(default=120, ge=1, alias="timeoutSeconds")
    secrets: dict[str, str] = Field(default_factory=dict)
    detach: bool = False
    priority: int = 0
    cancel: bool = False
    #: A job preempted for another (docs/operator.md) ends ``preempted``; true: the operator queues a copy of
    #: it (``status.requeuedAs``) that keeps its place in the queue.
    requeue_on_preemption: bool = Field(default=True, alias="requeueOnPreemption")
    ttl_seconds_after_finished: Optional[int] = Field(default=None, alias="ttlSecondsAfterFinished")
    #: Run first on a simulated twin of the embodiment; only a pre-flight that passes joins the real queue.
    preflight: Optional[PreflightSpec] = None


class Rollout(Wire):
    index: int = 0
    total: int = 0


class MonitorVerdict(Wire):
    """The cell's completion monitor's verdict on one rollout, kept even when an operator overruled it."""

    outcome: Literal["success", "failure"]
    score: float
    at: Timestamp
    frame_at: Optional[Timestamp] = Field(default=None, alias="frameAt")


class RolloutRecord(Wire):
    """One rollout as the node agent recorded it (``status.rollouts``): begin, end, the operator's verdict."""

    index: int = Field(ge=0)
    total: int = Field(ge=0)
    outcome: Literal["success", "failure", "unmarked"]
    marked_by: Optional[str] = Field(default=None, alias="markedBy")
    marked_at: Optional[Timestamp] = Field(default=None, alias="markedAt")
    started_at: Timestamp = Field(alias="startedAt")
    ended_at: Optional[Timestamp] = Field(default=None, alias="endedAt")
    #: The job asked for the cell operator's Success/Fail buttons (``rollout_begin(outcome_controls=...)``).
    outcome_controls: bool = Field(default=True, alias="outcomeControls")
    monitor: Optional[MonitorVerdict] = None


class RobotJobResult(Wire):
    exit_code: Optional[int] = Field(default=None, alias="exitCode")
    return_value: Any = Field(default=None, alias="returnValue")
    error: Optional[str] = None
    traceback: Optional[str] = None
    stdout_tail: str = Field(default="", alias="stdoutTail")
    stderr_tail: str = Field(default="", alias="stderrTail")


class JobArtifacts(Wire):
    """Where the job's output directory went (``status.artifacts``, written by the node agent after the job)."""

    phase: Optional[str] = None  # Pending | Uploading | Uploaded | Retrying | Failed | Discarded
    location: Optional[str] = None
    manifest: Optional[str] = None
    files: Optional[int] = None
    bytes: Optional[int] = None
    complete: Optional[bool] = None
    left_out: Optional[int] = Field(default=None, alias="leftOut")
    message: Optional[str] = None


class PreemptionRequest(Wire):
    """``status.preemption``: the operator asks the node agent to stop the run at its next episode boundary.

    The agent lets the open rollout end (``rollout_end``), then opens the grace window
    (``is_shutting_down()``); a job that reaches no boundary within ``episodeWaitSeconds``
    gets the grace window there. The run then ends ``preempted``.
    """

    requested_at: Timestamp = Field(alias="requestedAt")
    for_job: str = Field(alias="forJob", min_length=1, max_length=507)
    message: str = Field(min_length=1, max_length=1024)
    episode_wait_seconds: int = Field(alias="episodeWaitSeconds", ge=0, le=86400)


class PreflightStatus(Wire):
    """``status.preflight``: the operator's record of a job's pre-flight (``job``, a RobotJob of the same
    namespace) and its verdict: ``Running`` (the job waits), ``Passed`` (it joins the queue), ``Failed``
    (the job failed, reason ``PreflightFailed``)."""

    phase: Literal["Running", "Passed", "Failed"]
    job: str = Field(min_length=1, max_length=253)
    message: Optional[str] = Field(default=None, max_length=1024)
    started_at: Optional[Timestamp] = Field(default=None, alias="startedAt")
    finished_at: Optional[Timestamp] = Field(default=None, alias="finishedAt")


class RobotJobStatus(Wire):
    phase: Optional[str] = None
    job_id: Optional[str] = Field(default=None, alias="jobId")
    cell_name: Optional[str] = Field(default=None, alias="cellName")
    queued_reason: Optional[str] = Field(default=None, alias="queuedReason")
    queue_position: Optional[int] = Field(default=None, alias="queuePosition")
    estimated_start: Optional[Timestamp] = Field(default=None, alias="estimatedStart")
    likely_start: Optional[Timestamp] = Field(default=None, alias="likelyStart")
    started_at: Optional[Timestamp] = Field(default=None, alias="startedAt")
    finished_at: Optional[Timestamp] = Field(default=None, alias="finishedAt")
    progress: Optional[str] = None
    rollout: Optional[Rollout] = None
    rollouts: list[RolloutRecord] = Field(default_factory=list)
    result: Optional[RobotJobResult] = None
    artifacts: Optional[JobArtifacts] = None
    preemption: Optional[PreemptionRequest] = None
    #: The RobotJob the operator created to run this preempted job again (``spec.requeueOnPreemption``).
    requeued_as: Optional[str] = Field(default=None, alias="requeuedAs", max_length=253)
    preflight: Optional[PreflightStatus] = None
    #: When the operator first queued the job, in microseconds: its place among the jobs created in the
    #: same second (a creation time has whole seconds), kept so a later arrival never moves it back.
    arrived_at: Optional[Timestamp] = Field(default=None, alias="arrivedAt")
    conditions: list[Condition] = Field(default_factory=list)


class RobotJob(Wire):
    metadata: Metadata
    spec: RobotJobSpec
    status: RobotJobStatus = Field(default_factory=RobotJobStatus)


# -- Cell ------------------------------------------------------------------------------------


class CellArm(Wire):
    """One arm of a cell (``spec.robot``, or an entry of ``spec.arms``): facts of the cell, never of a job."""

    port: Optional[str] = None
    robot_id: Optional[str] = Field(default=None, alias="robotId")
    calibration_dir: Optional[str] = Field(default=None, alias="calibrationDir")
    safety_limit: Optional[float] = Field(default=None, alias="safetyLimit")


class CellCamera(Wire):
    index_or_path: int | str = Field(alias="indexOrPath")
    width: int = 640
    height: int = 480
    fps: int = 30


class DutyCycleSpec(Wire):
    """``spec.dutyCycle``: the cell rests ``restMinutes`` every ``everyHours`` (AutoEval's robots: 20 min every 6 h)."""

    rest_minutes: int = Field(alias="restMinutes", ge=1, le=1440)
    every_hours: float = Field(alias="everyHours", gt=0, le=168)


class DutyCycleStatus(Wire):
    """``status.dutyCycle``: when the cell's working time began, and until when it rests (absent: working)."""

    working_since: Optional[Timestamp] = Field(default=None, alias="workingSince")
    resting_until: Optional[Timestamp] = Field(default=None, alias="restingUntil")


class CellSpec(Wire):
    embodiment: str
    node_name: str = Field(alias="nodeName")
    task: Optional[str] = None
    unschedulable: bool = False
    simulated: bool = False
    #: A simulated twin for pre-flights only: the operator binds pre-flight runs to it and never an ordinary job.
    preflight: bool = False
    robot: Optional[CellArm] = None
    arms: dict[str, CellArm] = Field(default_factory=dict)
    cameras: dict[str, CellCamera] = Field(default_factory=dict)
    language_instruction: Optional[str] = Field(default=None, alias="languageInstruction")
    grace_period_seconds: int = Field(default=10, ge=0, alias="gracePeriodSeconds")
    reset_timeout_seconds: int = Field(default=300, ge=0, alias="resetTimeoutSeconds")
    safety_policy: Literal["clamp", "trip"] = Field(default="clamp", alias="safetyPolicy")
    allow_calibration_jobs: bool = Field(default=False, alias="allowCalibrationJobs")
    register_bounds: dict[str, tuple[int, int]] = Field(default_factory=dict, alias="registerBounds")
    duty_cycle: Optional[DutyCycleSpec] = Field(default=None, alias="dutyCycle")
    completion: Any = None
    """The completion monitor's settings as written: a reader that runs or checks them validates them
    with ``armnet_core.cell_completion.CompletionConfig`` (the node agent, the operator), one that
    only shows them reads them leniently (the client)."""
    reset: Any = None
    """How ``ctx.cell.reset()`` puts the workspace back (``Operator`` or ``Scripted`` poses), as written: a
    reader that runs it validates it with ``armnet_core.cell_completion.ResetConfig`` and ``reset_problem``
    (the node agent), one that only shows it reads it leniently."""


class CellQueue(Wire):
    """The operator's summary of the queue at one cell (``status.queue``), for the cell operator's page.

    Counts and times only: a Cell is read by every tenant, so it never names another
    tenant's waiting job.
    """

    waiting_jobs: int = Field(default=0, ge=0, alias="waitingJobs")
    likely_free: Optional[Timestamp] = Field(default=None, alias="likelyFree")
    latest_free: Optional[Timestamp] = Field(default=None, alias="latestFree")


class CellStatus(Wire):
    phase: Optional[str] = None
    current_job: Optional[str] = Field(default=None, alias="currentJob")
    claimed_at: Optional[Timestamp] = Field(default=None, alias="claimedAt")
    last_heartbeat_time: Optional[Timestamp] = Field(default=None, alias="lastHeartbeatTime")
    message: Optional[str] = None
    conditions: list[Condition] = Field(default_factory=list)
    queue: Optional[CellQueue] = None
    duty_cycle: Optional[DutyCycleStatus] = Field(default=None, alias="dutyCycle")


class Cell(Wire):
    metadata: Metadata
    spec: CellSpec
    status: CellStatus = Field(default_factory=CellStatus)


# -- CellQuota -------------------------------------------------------------------------------


class QuotaPreemption(Wire):
    """Which running jobs of the tenant a waiting job of the same tenant may preempt (Kueue's ``withinClusterQueue``)."""

    within_quota: Literal["Never", "LowerPriority"] = Field(default="Never", alias="withinQuota")


class CellQuotaSpec(Wire):
    """A tenant's share of one embodiment's cells, with the CRD's rules (an object stored before them still parses)."""

    namespace: str = Field(min_length=1, max_length=63, pattern=r"^[a-z0-9]([-a-z0-9]*[a-z0-9])?$")
    embodiment: str = Field(min_length=1, max_length=253)
    task: Optional[str] = Field(default=None, min_length=1, max_length=253)
    nominal_cells: int = Field(alias="nominalCells", ge=0, le=100_000)
    borrowing_limit: Optional[int] = Field(default=None, alias="borrowingLimit", ge=0, le=100_000)
    weight: float = Field(default=1.0, gt=0, le=1000)
    cohort: Optional[str] = Field(default=None, min_length=1, max_length=63)
    credits_cell_hours: Optional[float] = Field(default=None, alias="creditsCellHours", ge=0)
    period: Optional[Literal["Day", "Week"]] = None
    preemption: QuotaPreemption = Field(default_factory=QuotaPreemption)

    @model_validator(mode="after")
    def _the_crds_rules(self) -> CellQuotaSpec:
        if (self.credits_cell_hours is None) != (self.period is None):
            raise ValueError("creditsCellHours and period go together (credits are granted per period)")
        if self.borrowing_limit is not None and self.cohort is None:
            raise ValueError("borrowingLimit needs a cohort to borrow from")
        return self


class QuotaUsage(Wire):
    """Cell time a tenant used (``status.usage``), kept in the object so it survives operator restarts."""

    decayed_cell_seconds: float = Field(default=0.0, alias="decayedCellSeconds", ge=0)
    period_cell_seconds: float = Field(default=0.0, alias="periodCellSeconds", ge=0)
    period_start: Optional[Timestamp] = Field(default=None, alias="periodStart")
    updated_at: Optional[Timestamp] = Field(default=None, alias="updatedAt")


class CellQuotaStatus(Wire):
    cells_in_use: int = Field(default=0, alias="cellsInUse")
    borrowed_cells: int = Field(default=0, alias="borrowedCells")
    waiting_jobs: int = Field(default=0, alias="waitingJobs")
    usage: Optional[QuotaUsage] = None
    message: Optional[str] = None


class CellQuota(Wire):
    metadata: Metadata
    spec: CellQuotaSpec
    status: CellQuotaStatus = Field(default_factory=CellQuotaStatus)


__all__ = [
    "Cell",
    "CellArm",
    "CellCamera",
    "CellQueue",
    "CellQuota",
    "CellQuotaSpec",
    "CellQuotaStatus",
    "CellSpec",
    "CellStatus",
    "Condition",
    "DutyCycleSpec",
    "DutyCycleStatus",
    "JobArtifacts",
    "Metadata",
    "MonitorVerdict",
    "PreemptionRequest",
    "PreflightSpec",
    "PreflightStatus",
    "QuotaPreemption",
    "QuotaUsage",
    "RobotJob",
    "RobotJobResult",
    "RobotJobSpec",
    "RobotJobStatus",
    "Rollout",
    "RolloutRecord",
    "Timestamp",
    "Wire",
]

"""The Kubernetes API's vocabulary, defined once for every package that speaks it.

The operator, the node agent, the launch library, the FMS and the customer's client
all read and write RobotJobs and Cells; each used to declare the group, the version,
the phases, the condition types, the labels and the annotations it shares with another
itself. They import them from here, and ``tests/unit/architecture/test_api_vocabulary.py``
keeps this module in step with the CRDs in ``crds/`` (group, version, plurals, the phase
enums) and fails when a package spells one of these values again.
"""

from __future__ import annotations

from enum import Enum

from armnet_core.models import JobStatus, TerminalStatus


class _Name(str, Enum):  # noqa: UP042 - the SDK runs on Python 3.10, which has no enum.StrEnum
    """A name on the wire: a member is its plain string value, in ``str()`` and f-strings too.

    This is what ``enum.StrEnum`` does on Python 3.11, so ``f"{CellPhase.READY}"`` writes ``Ready``.
    """

    def __str__(self) -> str:
        return str.__str__(self)

    def __format__(self, format_spec: str) -> str:
        return str.__format__(self, format_spec)


GROUP = "armnet.io"
VERSION = "v1alpha1"
API_VERSION = f"{GROUP}/{VERSION}"

ROBOTJOBS = "robotjobs"
CELLS = "cells"
CELLQUOTAS = "cellquotas"


class JobPhase(_Name):
    """``RobotJob.status.phase``: the SDK's ``JobStatus`` values, as names that print as themselves
    (``str(JobStatus.RUNNING)`` stays ``JobStatus.RUNNING`` for the SDK's users)."""

    SUBMITTED = JobStatus.SUBMITTED.value
    QUEUED = JobStatus.QUEUED.value
    DISPATCHED = JobStatus.DISPATCHED.value
    RUNNING = JobStatus.RUNNING.value
    SUCCEEDED = JobStatus.SUCCEEDED.value
    FAILED = JobStatus.FAILED.value
    TIMEOUT = JobStatus.TIMEOUT.value
    CANCELLED = JobStatus.CANCELLED.value
    PREEMPTED = JobStatus.PREEMPTED.value


#: ``RobotJob.status.phase`` values, as plain strings (the SDK's ``JobStatus``).
PHASES: tuple[str, ...] = tuple(status.value for status in JobStatus)
#: A job in one of these phases holds its cell: the agent runs it.
ACTIVE_PHASES: frozenset[str] = frozenset({JobPhase.DISPATCHED.value, JobPhase.RUNNING.value})
#: A job in one of these phases has ended; nothing changes its phase again.
TERMINAL_PHASES: frozenset[str] = frozenset(status.value for status in TerminalStatus)


class CellPhase(_Name):
    """``Cell.status.phase``: the operator derives it from the spec, the heartbeat and the conditions."""

    READY = "Ready"
    BUSY = "Busy"
    OFFLINE = "Offline"
    FAULTED = "Faulted"
    CORDONED = "Cordoned"
    RESTING = "Resting"
    INVALID = "Invalid"


class CellConditionType(_Name):
    """The health conditions the node agent reports on a Cell; any ``False`` one faults the cell
    (the operator binds no job to it)."""

    AGENT_CONNECTED = "AgentConnected"
    HARDWARE_READY = "HardwareReady"
    CALIBRATION_PRESENT = "CalibrationPresent"
    CAMERAS_READY = "CamerasReady"
    INTERLOCK_CLEAR = "InterlockClear"
    #: Only on a cell whose completion monitor reads files on the robot host (a classifier's
    #: model, a judge's token file): they are where the agent allows and usable.
    COMPLETION_READY = "CompletionReady"


class ArtifactsPhase(_Name):
    """``RobotJob.status.artifacts.phase``: where the job's output directory is on its way to the
    object store (the node agent writes it, the client reads it)."""

    #: Written with the job's terminal status: its output waits its turn in the agent's upload
    #: queue, and a final phase follows (a client waiting for the result waits for that one too).
    PENDING = "Pending"
    UPLOADING = "Uploading"
    UPLOADED = "Uploaded"
    RETRYING = "Retrying"
    FAILED = "Failed"
    DISCARDED = "Discarded"


#: ``status.rollouts[].markedBy`` of an outcome the cell's completion monitor decided (a person's name otherwise).
MONITOR_MARKED_BY = "monitor"

#: The phases of an output the node agent is still at: a final one (Uploaded, Failed, Discarded) follows.
ARTIFACTS_IN_PROGRESS = frozenset({ArtifactsPhase.PENDING, ArtifactsPhase.UPLOADING, ArtifactsPhase.RETRYING})


class PreflightPhase(_Name):
    """``RobotJob.status.preflight.phase``: a job's pre-flight on a simulated twin (the operator writes it)."""

    RUNNING = "Running"
    PASSED = "Passed"
    FAILED = "Failed"


#: Not a health condition (the operator still binds: jobs run without NATS). The node agent
#: reports it on a Cell to tell the person at the cell and the platform team why the cell
#: operator's buttons and live logs do nothing.
STREAMS_CONNECTED_CONDITION = "StreamsConnected"
#: Not a health condition either (a person can still reset the cell, so the operator still binds).
#: On a cell with ``spec.reset.mode: Scripted`` the node agent reports whether its latest scripted
#: reset worked; False: it fell back to the person at the cell, who should look at the workspace.
AUTO_RESET_CONDITION = "AutoResetWorking"

#: Keys on RobotJobs and Cells that one process writes and another reads.
#: The cell operator's page (FMS) writes who stopped a job; the node agent puts it in the job's error.
STOPPED_BY_ANNOTATION = f"{GROUP}/stopped-by"
#: ``armnet submit --follow`` asks for a cancel when its client is gone this long; the node agent applies it.
FOLLOWER_TIMEOUT_ANNOTATION = f"{GROUP}/follower-timeout-seconds"
#: Characters of a stop's reason (a cancel's, a preemption's) on the connector's agent socket: it lands
#: in the interlock's message and the job's record.
MAX_STOP_REASON = 500
#: On the RobotJob the operator creates to run a preempted job again: the preempted job's uid (the requeue
#: is created once per preempted job) and when the preempted job first queued (it keeps its place).
PREEMPTED_FROM_ANNOTATION = f"{GROUP}/preempted-from"
QUEUED_SINCE_ANNOTATION = f"{GROUP}/queued-since"
#: On the RobotJob the operator creates to run a job's pre-flight on a simulated twin (``spec.preflight``):
#: the job's uid. The pre-flight is created once per job, runs only on pre-flight cells and is rationed by no
#: CellQuota (it never uses a real cell).
PREFLIGHT_FOR_ANNOTATION = f"{GROUP}/preflight-for"
#: On a RobotJob, ``"true"``: its stored outputs outlive it (the operator removes a job's outputs with the
#: job at its ``ttlSecondsAfterFinished`` otherwise). Set it any time before the TTL, e.g. ``kubectl annotate``.
KEEP_ARTIFACTS_ANNOTATION = f"{GROUP}/keep-artifacts"
#: The operator's finalizer on a RobotJob: the job's cell is released before the job is deleted.
RELEASE_CELL_FINALIZER = f"{GROUP}/release-cell"
#: The label by which the cell operator's page groups Cells (set by whoever installs the cells).
SITE_LABEL = f"{GROUP}/site"
#: Simulated cells only: ``arm/motor`` (comma-separated) of servos the node agent unplugs in the
#: simulator, so a platform team can watch the cell go unhealthy (fault injection).
SIM_UNPLUG_ANNOTATION = f"{GROUP}/sim-unplug"

#: Labels tying a job's container or pod to its cell and job (``armnet_launch.plan`` sets them):
#: the node agent finds and re-adopts what it started by them, after a restart too.
CELL_LABEL = f"{GROUP}/cell"
JOB_UID_LABEL = f"{GROUP}/job-uid"
NAMESPACE_LABEL = f"{GROUP}/namespace"
NAME_LABEL = f"{GROUP}/name"
MANAGED_BY_LABEL = f"{GROUP}/managed-by"
#: A local run's container (``armnet run``): the run's job id, to find it with ``docker ps``.
JOB_ID_LABEL = f"{GROUP}/job-id"
#: On a job's pod (the pod launcher): its RobotJob's ``namespace/name`` and its timeout in seconds.
JOB_ANNOTATION = f"{GROUP}/job"
TIMEOUT_ANNOTATION = f"{GROUP}/timeout-seconds"
#: A cell's extended resource is this prefix and the cell's name: the node agent's device plugin
#: serves it, a job's pod requests it, so the kubelet starts the pod on the cell's node only.
CELL_RESOURCE_PREFIX = f"{GROUP}/cell-"

#: The object store of job outputs, as the node agent reads it from its env (the chart's
#: ``artifacts`` values) and the client too (``armnet artifacts``; docs/outputs.md).
ARTIFACTS_ENDPOINT_ENV = "ARMNET_ARTIFACTS_ENDPOINT"
ARTIFACTS_BUCKET_ENV = "ARMNET_ARTIFACTS_BUCKET"
ARTIFACTS_REGION_ENV = "ARMNET_ARTIFACTS_REGION"
ARTIFACTS_ACCESS_KEY_ENV = "ARMNET_ARTIFACTS_ACCESS_KEY_ID"
ARTIFACTS_SECRET_KEY_ENV = "ARMNET_ARTIFACTS_SECRET_ACCESS_KEY"

__all__ = [
    "ARTIFACTS_ACCESS_KEY_ENV",
    "ARTIFACTS_BUCKET_ENV",
    "ARTIFACTS_ENDPOINT_ENV",
    "ARTIFACTS_IN_PROGRESS",
    "ARTIFACTS_REGION_ENV",
    "ARTIFACTS_SECRET_KEY_ENV",
    "ACTIVE_PHASES",
    "API_VERSION",
    "ArtifactsPhase",
    "CELLQUOTAS",
    "CELLS",
    "CELL_LABEL",
    "CELL_RESOURCE_PREFIX",
    "CellConditionType",
    "CellPhase",
    "FOLLOWER_TIMEOUT_ANNOTATION",
    "GROUP",
    "JOB_ANNOTATION",
    "JOB_ID_LABEL",
    "JOB_UID_LABEL",
    "JobPhase",
    "MANAGED_BY_LABEL",
    "NAMESPACE_LABEL",
    "MAX_STOP_REASON",
    "MONITOR_MARKED_BY",
    "NAME_LABEL",
    "PREEMPTED_FROM_ANNOTATION",
    "KEEP_ARTIFACTS_ANNOTATION",
    "PREFLIGHT_FOR_ANNOTATION",
    "PreflightPhase",
    "QUEUED_SINCE_ANNOTATION",
    "PHASES",
    "RELEASE_CELL_FINALIZER",
    "ROBOTJOBS",
    "SIM_UNPLUG_ANNOTATION",
    "SITE_LABEL",
    "STOPPED_BY_ANNOTATION",
    "STREAMS_CONNECTED_CONDITION",
    "AUTO_RESET_CONDITION",
    "TERMINAL_PHASES",
    "TIMEOUT_ANNOTATION",
    "VERSION",
]

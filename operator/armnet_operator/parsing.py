"""The boundary: RobotJob and Cell bodies from the API server into frozen models.

The platform's models (``armnet_core.resources``, the one set every reader uses)
validate the parts the operator relies on (the CRD schema already rejected most bad
input; this guards against older objects and hand-written status). Unknown fields
are ignored so the agent can add its own. A bad status field is read as absent and
repaired; a bad spec field fails the job, or keeps the cell from being bound.
"""

from __future__ import annotations

from collections.abc import Mapping
from datetime import UTC, datetime, timedelta
from typing import Any, TypeVar

from armnet_core.api import (
    KEEP_ARTIFACTS_ANNOTATION,
    PREEMPTED_FROM_ANNOTATION,
    PREFLIGHT_FOR_ANNOTATION,
    QUEUED_SINCE_ANNOTATION,
)
from armnet_core.cell_completion import CompletionConfig, unknown_camera
from armnet_core.lenient import read_parts
from armnet_core.resources import (
    CellArm,
    CellSpec,
    CellStatus,
    Condition,
    Metadata,
    RobotJobSpec,
    RobotJobStatus,
    Wire,
)
from armnet_core.resources import (
    CellQueue as CellQueueStatus,
)
from armnet_core.times import parse_time
from pydantic import BaseModel, Field, ValidationError

from .args import args_problem, measure
from .duty_cycle import NO_STATE, DutyCycle, DutyState
from .model import (
    Arm,
    Cell,
    CellConditionType,
    CellPhase,
    CellQueue,
    Job,
    JobConditionType,
    JobPhase,
    PreflightPhase,
)

_Model = TypeVar("_Model", bound=BaseModel)

_HEALTH_TYPES = frozenset(CellConditionType)


class _JobStatus(RobotJobStatus):
    """The platform's model, with the phase narrowed to the operator's: an unknown phase is a defect to repair."""

    phase: JobPhase | None = None


def _preflight_phase(status: Any) -> PreflightPhase | None:
    return PreflightPhase(status.preflight.phase) if status.preflight is not None else None


class _CellStatus(CellStatus):
    phase: CellPhase | None = None


class _JobBody(Wire):
    metadata: Metadata
    spec: RobotJobSpec
    status: _JobStatus = Field(default_factory=_JobStatus)


def _true_since(conditions: list[Condition], type_: str) -> datetime | None:
    for condition in conditions:
        if condition.type == type_ and condition.status == "True":
            return condition.last_transition_time
    return None


def _lenient(model: type[_Model], raw: Mapping[str, Any], section: str) -> tuple[_Model, list[str]]:
    """Validate ``raw``; fields that fail are dropped (read as absent) and named in the list.

    A status is written by the agent, by other tools and by hand: one bad
    timestamp must not hide the whole object from the operator (its finalizer
    could then never be removed). The caller repairs the named fields.
    """
    reading = read_parts(model, dict(raw))
    defects = [f"{section}.{part}" for part in reading.dropped]
    if reading.value is None:
        return model.model_validate({}), defects + [section]
    return reading.value, defects


def _conditions(raw: Any, section: str) -> tuple[list[Condition], list[dict[str, Any]], list[str]]:
    """Each condition on its own: a bad one is dropped and named, the rest kept."""
    if not isinstance(raw, list | tuple):
        return [], [], [] if raw is None else [section]
    parsed: list[Condition] = []
    plain: list[dict[str, Any]] = []
    defects: list[str] = []
    for index, item in enumerate(raw):
        try:
            parsed.append(Condition.model_validate(_plain(item)))
        except ValidationError:
            defects.append(f"{section}[{index}]")
            continue
        plain.append(_plain(item))
    return parsed, plain, defects


_JOB_SPEC_FIELDS = ("image", "embodiment", "task", "priority", "cancel", "ttlSecondsAfterFinished", "timeoutSeconds",
                    "requeueOnPreemption", "preflight")
_JOB_STATUS_SCALARS = ("phase", "cellName", "jobId", "queuedReason", "queuePosition", "finishedAt", "startedAt",
                       "estimatedStart", "likelyStart", "preemption", "requeuedAs", "preflight", "arrivedAt",
                       "artifacts")
_JOB_STATUS_FIELDS = (*_JOB_STATUS_SCALARS, "conditions")


def parse_job(body: Mapping[str, Any]) -> Job:
    """The job as the operator sees it; never raises on a bad spec or status field.

    The common case is one validation of the whole body; only a body with a
    bad field takes the slower field-by-field path (``_parse_job_leniently``).
    """
    raw_spec = body.get("spec") or {}
    raw_status = body.get("status") or {}
    if not isinstance(raw_spec, Mapping) or not isinstance(raw_status, Mapping):
        return _parse_job_leniently(body)
    try:
        raw = _JobBody.model_validate({
            "metadata": _metadata(body),
            "spec": {k: _plain(raw_spec[k]) for k in _JOB_SPEC_FIELDS if k in raw_spec},
            "status": {k: _plain(raw_status[k]) for k in _JOB_STATUS_FIELDS if k in raw_status},
        })
    except ValidationError:
        return _parse_job_leniently(body)
    problem = args_problem(raw_spec["args"]) if "args" in raw_spec else None
    meta, spec, status = raw.metadata, raw.spec, raw.status
    return _job(meta, spec, status, status.conditions, tuple(_plain(raw_status.get("conditions") or [])),
                spec_problem=problem)


def _parse_job_leniently(body: Mapping[str, Any]) -> Job:
    """Field by field, for a body with a bad field.

    A spec field that cannot be read (or args beyond the limits) makes a job
    that fails with the reason; a status field that cannot be read is treated
    as absent and named in ``status_defects`` so it gets repaired.
    """
    meta = Metadata.model_validate(_metadata(body))
    raw_spec = body.get("spec") or {}
    spec_fields = {k: _plain(raw_spec[k]) for k in _JOB_SPEC_FIELDS if isinstance(raw_spec, Mapping) and k in raw_spec}
    problems: list[str] = []
    try:
        spec = RobotJobSpec.model_validate(spec_fields)
    except ValidationError as error:
        problems.append("; ".join(f"spec.{'.'.join(map(str, e['loc']))}: {e['msg']}" for e in error.errors()))
        bad = {str(e["loc"][0]) for e in error.errors() if e["loc"]}
        good = {k: v for k, v in spec_fields.items() if k not in bad}
        spec = RobotJobSpec.model_validate({"image": "", "embodiment": "", **good})
    if isinstance(raw_spec, Mapping) and "args" in raw_spec:
        too_big = args_problem(raw_spec["args"])
        if too_big:
            problems.append(too_big)
    raw_status = body.get("status") or {}
    raw_status = raw_status if isinstance(raw_status, Mapping) else {}
    scalars = {k: _plain(v) for k, v in raw_status.items() if k in _JOB_STATUS_SCALARS}
    status, defects = _lenient(_JobStatus, scalars, "status")
    conditions, plain_conditions, bad_conditions = _conditions(raw_status.get("conditions"), "status.conditions")
    return _job(meta, spec, status, conditions, tuple(plain_conditions),
                spec_problem="; ".join(problems) or None, status_defects=tuple(defects + bad_conditions))


def _job(
    meta: Any, spec: Any, status: Any, conditions: Any, plain_conditions: tuple[Any, ...], *,
    spec_problem: str | None, status_defects: tuple[str, ...] = (),
) -> Job:
    """The frozen ``Job`` from parsed metadata, spec and status (both parsing paths end here)."""
    created = meta.creation_timestamp or datetime.now(UTC)
    return Job(
        namespace=meta.namespace or "",
        name=meta.name,
        created=queued_since(meta.annotations, created),
        embodiment=spec.embodiment,
        task=spec.task or None,
        priority=spec.priority,
        uid=meta.uid or "",
        resource_version=meta.resource_version or "",
        cancel=spec.cancel,
        deleting=meta.deletion_timestamp is not None,
        finalizers=tuple(meta.finalizers),
        phase=status.phase,
        cell_name=status.cell_name or None,
        job_id=status.job_id,
        queued_reason=status.queued_reason,
        queue_position=status.queue_position,
        bound_at=_true_since(conditions, JobConditionType.BOUND),
        queued_at=_true_since(conditions, JobConditionType.QUEUED),
        cancel_requested_at=_true_since(conditions, JobConditionType.CANCEL_REQUESTED),
        finished_at=status.finished_at,
        ttl_seconds_after_finished=spec.ttl_seconds_after_finished,
        timeout_seconds=spec.timeout_seconds,
        started_at=status.started_at,
        estimated_start=status.estimated_start,
        likely_start=status.likely_start,
        conditions=plain_conditions,
        spec_problem=spec_problem,
        status_defects=status_defects,
        requeue_on_preemption=spec.requeue_on_preemption,
        preemption_requested_at=status.preemption.requested_at if status.preemption is not None else None,
        requeued_as=status.requeued_as,
        preflight_seconds=spec.preflight.seconds if spec.preflight is not None else None,
        preflight_phase=_preflight_phase(status),
        preflight_job=status.preflight.job if status.preflight is not None else None,
        preflight_for=meta.annotations.get(PREFLIGHT_FOR_ANNOTATION) or None,
        arrived_at=status.arrived_at,
        artifacts_location=status.artifacts.location if status.artifacts is not None else None,
        artifacts_phase=status.artifacts.phase if status.artifacts is not None else None,
        keep_artifacts=meta.annotations.get(KEEP_ARTIFACTS_ANNOTATION) == "true",
    )


def queued_since(annotations: Mapping[str, str], created: datetime) -> datetime:
    """When the job joined the queue: a preempted job's requeue keeps the place of the job it repeats.

    Only ever earlier than the object's creation (the operator writes it when it
    creates the requeue); a value that does not parse is ignored. A tenant who
    writes it on their own job moves that job ahead only as far as a priority could.
    """
    since = parse_time(annotations.get(QUEUED_SINCE_ANNOTATION)) if annotations.get(PREEMPTED_FROM_ANNOTATION) else None
    return since if since is not None and since < created else created


def parse_cell(body: Mapping[str, Any]) -> Cell:
    meta = Metadata.model_validate(_metadata(body))
    raw_spec = body.get("spec") or {}
    fields = _plain({k: v for k, v in raw_spec.items()
                     if k in ("embodiment", "task", "nodeName", "unschedulable", "gracePeriodSeconds",
                              "simulated", "preflight", "dutyCycle")})
    problem = None
    try:
        spec = CellSpec.model_validate(fields)
    except ValidationError as error:
        # Still in view (so its claim and phase are handled), but never bound until fixed.
        problem = "; ".join(f"spec.{'.'.join(map(str, e['loc']))}: {e['msg']}" for e in error.errors())
        bad = {str(e["loc"][0]) for e in error.errors() if e["loc"]}
        spec = CellSpec.model_validate({"embodiment": "", "nodeName": "", **{k: v for k, v in fields.items() if k not in bad}})
    if spec.preflight and not spec.simulated:
        # The CRD refuses it; an object stored before the rule is never bound, rather than run as a twin.
        why = "spec.preflight: a pre-flight cell must be simulated (spec.simulated: true)"
        problem = f"{problem}; {why}" if problem else why
    completion = _completion_problem(raw_spec)
    if completion is not None:
        problem = f"{problem}; {completion}" if problem else completion
    raw_status = body.get("status") or {}
    scalars = {k: _plain(v) for k, v in raw_status.items() if k != "conditions"}
    status, _defects = _lenient(_CellStatus, scalars, "status")
    conditions, _, _ = _conditions(raw_status.get("conditions"), "status.conditions")
    failing = tuple(
        sorted(c.type for c in conditions if c.type in _HEALTH_TYPES and c.status == "False")
    )
    return Cell(
        name=meta.name,
        embodiment=spec.embodiment,
        task=spec.task or None,
        resource_version=meta.resource_version or "",
        node_name=spec.node_name,
        unschedulable=spec.unschedulable,
        grace_period=timedelta(seconds=spec.grace_period_seconds),
        phase=status.phase,
        current_job=status.current_job or None,
        claimed_at=status.claimed_at,
        last_heartbeat=status.last_heartbeat_time,
        failing_conditions=failing,
        uid=meta.uid or "",
        created=meta.creation_timestamp,
        arms=_arms(raw_spec),
        message=status.message or None,
        spec_problem=problem,
        queue=_cell_queue(status.queue),
        preflight=spec.preflight,
        duty_cycle=None if spec.duty_cycle is None else DutyCycle(
            rest=timedelta(minutes=spec.duty_cycle.rest_minutes), every=timedelta(hours=spec.duty_cycle.every_hours)),
        duty=NO_STATE if status.duty_cycle is None else DutyState(
            status.duty_cycle.working_since, status.duty_cycle.resting_until),
    )


def _cell_queue(queue: CellQueueStatus | None) -> CellQueue:
    if queue is None:
        return CellQueue()
    return CellQueue(queue.waiting_jobs, queue.likely_free, queue.latest_free)


#: How deep a ``spec.completion`` may nest (it holds ``region`` and ``colour`` objects: 2) and
#: how large it may be as JSON: far above any real setting, far below what parsing it costs.
COMPLETION_DEPTH = 4
COMPLETION_BYTES = 64 * 1024


def _completion_problem(spec: Mapping[str, Any]) -> str | None:
    """Why ``spec.completion`` cannot run (the connector's own model says), None when it can or is absent.

    The CRD refuses these at apply; a Cell stored before the schema, or with
    validation off, would otherwise be bound and its job's connector refuse to start.
    """
    raw = spec.get("completion")
    if raw is None:
        return None
    depth, size = measure(raw, COMPLETION_DEPTH, COMPLETION_BYTES)  # iterative: any depth is safe to measure
    if depth > COMPLETION_DEPTH:
        return f"spec.completion: nested deeper than {COMPLETION_DEPTH} levels; it holds a region and a colour at most"
    if size > COMPLETION_BYTES:
        return f"spec.completion: larger than {COMPLETION_BYTES} bytes as JSON; a completion setting is a few hundred"
    try:
        completion = CompletionConfig.model_validate(_plain(raw))
    except ValidationError as error:
        return "; ".join(
            f"spec.completion{''.join(f'.{part}' for part in e['loc'])}: {e['msg']}" for e in error.errors())
    cameras = spec.get("cameras")
    why = unknown_camera(completion, cameras if isinstance(cameras, Mapping) else {})
    return f"spec.{why}" if why else None


def _arms(spec: Mapping[str, Any]) -> tuple[Arm, ...]:
    """``spec.robot`` (named ``robot``) or each ``spec.arms`` entry; unreadable values are left out."""
    raw: dict[str, Any] = {}
    if isinstance(spec.get("robot"), Mapping):
        raw["robot"] = spec["robot"]
    if isinstance(spec.get("arms"), Mapping):
        raw.update({f"arms.{name}": arm for name, arm in spec["arms"].items() if isinstance(arm, Mapping)})
    arms = []
    for name, body in sorted(raw.items()):
        arm, _ = _lenient(CellArm, _plain(body), f"spec.{name}")
        arms.append(Arm(name, arm.port, arm.robot_id, arm.calibration_dir, arm.safety_limit))
    return tuple(arms)


def _metadata(body: Mapping[str, Any]) -> dict[str, Any]:
    """The metadata the models read; ``managedFields`` (large, unused) is skipped, not copied."""
    meta = body.get("metadata") or {}
    return {key: _plain(item) for key, item in meta.items() if key != "managedFields"}


def _plain(value: Any) -> Any:
    """kopf hands out read-only mapping views; pydantic wants plain dicts and lists.

    Only small, schema-bounded parts go through here (never ``spec.args``).
    """
    if isinstance(value, Mapping):
        return {key: _plain(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(item) for item in value]
    return value

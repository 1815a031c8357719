"""The Cell and RobotJob as the agent reads them: the platform's models at the boundary, frozen inside. Pure.

The spec is validated with ``armnet_core.resources`` (the one set of models every
reader uses); only the fields the agent acts on are kept, everything else in the
objects is ignored (the operator owns it). A malformed object is a ``ValueError`` naming
the field, reported on the object rather than crashing the agent.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any

from armnet_core.api import STOPPED_BY_ANNOTATION, JobPhase
from armnet_core.cell_completion import CompletionConfig, ResetConfig, reset_problem, unknown_camera
from armnet_core.resources import CellArm, CellSpec, PreemptionRequest, RobotJobSpec
from armnet_core.times import parse_time
from armnet_launch.cell_spec import CameraSpec
from pydantic import ValidationError

from armnet_node import rollout_history
from armnet_node.follower_rule import follower_window

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Cell:
    name: str
    node_name: str
    embodiment: str
    task: str | None
    simulated: bool
    arms: dict[str, CellArm]  # the core model: frozen, the fields the launch reads
    cameras: tuple[CameraSpec, ...]
    language_instruction: str | None
    grace_seconds: float
    reset_timeout_seconds: float
    #: The cell's safety settings, passed to its connector as they are (docs/connector.md).
    safety_policy: str = "clamp"
    allow_calibration_jobs: bool = False
    register_bounds: dict[str, tuple[int, int]] = field(default_factory=dict)
    #: The cell's completion monitor settings (``spec.completion``), None: operators only.
    completion: CompletionConfig | None = None
    #: How ``ctx.cell.reset()`` puts the workspace back (``spec.reset``), None: the operator confirms.
    reset: ResetConfig | None = None
    current_job: str | None = None
    annotations: dict[str, str] = field(default_factory=dict)
    resource_version: str = ""


@dataclass(frozen=True)
class Job:
    namespace: str
    name: str
    uid: str
    image: str
    embodiment: str
    args: dict[str, Any]
    timeout_seconds: int
    secrets: dict[str, str]
    cancel: bool
    deleting: bool
    phase: str | None
    cell_name: str | None
    started_at: datetime | None
    resource_version: str = ""
    #: The cell operator who stopped the job from the FMS (``armnet.io/stopped-by``), if any.
    stopped_by: str | None = None
    #: The heartbeat window of a job whose client follows it (``node.follower``); None: not watched.
    follower_window_s: float | None = None
    #: ``status.rollouts`` as last written (kept when an agent restart re-adopts the job).
    rollouts: rollout_history.History = ()
    #: The operator's request to stop the run at its next episode boundary (``status.preemption``), if any.
    preemption: PreemptionRequest | None = None
    #: ``spec.requeueOnPreemption``: a preempted run goes back to the queue (told to clients on its stream).
    requeue_on_preemption: bool = True

    @property
    def key(self) -> str:
        """``namespace/name``, as the Cell's ``status.currentJob`` names it."""
        return f"{self.namespace}/{self.name}"

    @property
    def stopping(self) -> bool:
        return self.cancel or self.deleting


def parse_cell(obj: dict[str, Any]) -> Cell:
    meta = obj.get("metadata") or {}
    try:
        spec = CellSpec.model_validate(obj.get("spec") or {})
        completion = None if spec.completion is None else CompletionConfig.model_validate(spec.completion)
        reset = None if spec.reset is None else ResetConfig.model_validate(spec.reset)
    except ValidationError as exc:
        raise ValueError(f"Cell {meta.get('name')}: invalid spec: {exc}") from exc
    arms = dict(spec.arms) or {"arm": spec.robot or CellArm()}
    problem = unknown_camera(completion, spec.cameras) or reset_problem(reset, completion, arms)
    if problem is not None:
        raise ValueError(f"Cell {meta.get('name')}: invalid spec: {problem}")
    status = obj.get("status") or {}
    return Cell(
        name=str(meta.get("name", "")),
        node_name=spec.node_name,
        embodiment=spec.embodiment,
        task=spec.task,
        simulated=spec.simulated,
        arms=arms,
        cameras=tuple(
            CameraSpec(name, c.width, c.height, c.fps, c.index_or_path) for name, c in sorted(spec.cameras.items())
        ),
        language_instruction=spec.language_instruction,
        grace_seconds=float(spec.grace_period_seconds),
        reset_timeout_seconds=float(spec.reset_timeout_seconds),
        safety_policy=spec.safety_policy,
        allow_calibration_jobs=spec.allow_calibration_jobs,
        register_bounds=dict(spec.register_bounds),
        completion=completion,
        reset=reset,
        current_job=status.get("currentJob"),
        annotations=dict(meta.get("annotations") or {}),
        resource_version=str(meta.get("resourceVersion", "")),
    )


def parse_job(obj: dict[str, Any]) -> Job:
    meta = obj.get("metadata") or {}
    where = f"RobotJob {meta.get('namespace')}/{meta.get('name')}"
    try:
        spec = RobotJobSpec.model_validate(obj.get("spec") or {})
    except ValidationError as exc:
        raise ValueError(f"{where}: invalid spec: {exc}") from exc
    status = obj.get("status") or {}
    started = status.get("startedAt")
    return Job(
        namespace=str(meta.get("namespace", "")),
        name=str(meta.get("name", "")),
        uid=str(meta.get("uid", "")),
        image=spec.image,
        embodiment=spec.embodiment,
        args=spec.args,
        timeout_seconds=spec.timeout_seconds,
        secrets=spec.secrets,
        cancel=spec.cancel,
        deleting=meta.get("deletionTimestamp") is not None,
        phase=status.get("phase"),
        cell_name=status.get("cellName"),
        started_at=parse_time(started),
        resource_version=str(meta.get("resourceVersion", "")),
        stopped_by=_operator_name((meta.get("annotations") or {}).get(STOPPED_BY_ANNOTATION)),
        follower_window_s=follower_window(meta.get("annotations") or {}, spec.detach),
        rollouts=rollout_history.from_status(status.get("rollouts")),
        preemption=parse_preemption(status.get("preemption"), where),
        requeue_on_preemption=spec.requeue_on_preemption,
    )


def parse_preemption(data: Any, where: str) -> PreemptionRequest | None:
    """``status.preemption``, or None when absent or malformed.

    A malformed request is logged and ignored rather than failing the whole job: the
    run goes on, and the operator, which wrote it, is the one to fix it (a job it
    cannot preempt still ends, at its timeout at the latest).
    """
    if data is None:
        return None
    try:
        return PreemptionRequest.model_validate(data)
    except ValidationError as exc:
        log.warning("%s: status.preemption ignored, it is invalid: %s", where, str(exc)[:500])
        return None


def _operator_name(value: Any) -> str | None:
    """The annotation's operator name if it is a plain short name (it lands in the job's result)."""
    if isinstance(value, str) and 0 < len(value) <= 64 and all(c.isalnum() or c in ".-_@" for c in value):
        return value
    return None


def cancel_reason(job: Job) -> str | None:
    """Why a cancelled job ended, when more is known than "cancelled": the FMS's Stop names the operator."""
    return f"stopped by cell operator {job.stopped_by}" if job.cancel and job.stopped_by else None


def should_launch(job: Job, cell: Cell) -> bool:
    """The operator's contract: dispatched, bound to this cell, and the cell names it back."""
    return (
        job.phase == JobPhase.DISPATCHED
        and job.cell_name == cell.name
        and cell.current_job == job.key
        and not job.stopping
    )

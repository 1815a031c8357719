"""The launch plan of one job on one cell: cell shape, directories, env, container. Pure.

From the RobotJob, the Cell, the agent's settings and the job's resolved
secrets, this decides everything the launch does, before anything starts: the
simulated cell spec the connector serves, where the sockets, calibration, cache
and volume live on the host, the SDK env vars (exactly ``armnet_runtime.env``),
and the customer container with its mounts and labels. A plan that cannot run
(an unsupported cell, an env the kernel would refuse) is a :class:`LaunchError`
whose message the job's ``result.error`` carries.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path

from armnet_core.cell_completion import (
    DEFAULT_COMPLETION_DIRS,
    CompletionConfig,
    host_files,
    outside_dirs,
)
from armnet_launch.cell_spec import (
    EMBODIMENT_PRESET,
    CellLayout,
    LocalCellSpec,
    build_job_env,
    plan_layout,
)
from armnet_launch.plan import (
    LABEL_CELL,
    LABEL_JOB_UID,
    LABEL_MANAGED_BY,
    LABEL_NAME,
    LABEL_NAMESPACE,
    MANAGED_BY_AGENT,
    ContainerSpec,
    Mount,
    oversized_env,
)
from armnet_runtime import env as env_keys

from armnet_node.model import Cell, Job

DEFAULT_SAFETY_LIMIT = 10.0


class LaunchError(ValueError):
    """The job cannot be launched as specified; the message says what to fix."""


@dataclass(frozen=True)
class HostPaths:
    """Where the agent keeps per-job, per-cell and per-namespace directories on the host."""

    state_dir: Path
    #: Read-only host paths mounted at the same path (development images that use the host's venv).
    dev_mounts: tuple[str, ...] = ()
    #: Extra env for the customer container (development images: PATH to the mounted venv).
    dev_env: Mapping[str, str] | None = None
    #: The host directories a Cell's completion monitor may read files from (a classifier's
    #: model, a judge's token file); any other path is refused (``completion_model``).
    completion_dirs: tuple[str, ...] = DEFAULT_COMPLETION_DIRS

    def run_dir(self, job_uid: str) -> Path:
        """Short on purpose: a unix socket path must stay under 108 bytes."""
        return self.state_dir / "run" / job_uid

    def cache_dir(self, cell: str) -> Path:
        return self.state_dir / "cells" / cell / "cache"

    def volume_dir(self, namespace: str) -> Path:
        return self.state_dir / "volumes" / namespace

    def output_dir(self, job_uid: str) -> Path:
        """Apart from the run directory (removed when the job ends): kept until its upload finished."""
        return self.state_dir / "outputs" / job_uid

    def record_dir(self, job_uid: str) -> Path:
        """The cell's record of the job (the connector writes it, the job never sees it); uploaded with the output."""
        return self.state_dir / "records" / job_uid

    @property
    def completion_models_dir(self) -> Path:
        """Where the agent writes the classifier models Cells name by ConfigMap (``completion_configmap``)."""
        return self.state_dir / "completion-models"

    def completion_models_of(self, cell: str) -> Path:
        """Where the agent writes the model of ``cell``'s ConfigMap: a folder of that cell's alone."""
        return self.completion_models_dir / cell

    def completion_dirs_for(self, completion: CompletionConfig | None, cell: str) -> tuple[str, ...]:
        """Where ``cell``'s completion files may lie: the configured directories, and for a classifier's model
        the agent's copy of that cell's ConfigMap too (never another cell's, whose pruning could remove it; never
        for a judge's token file, whose bytes go to the judge)."""
        if completion is not None and completion.classifier is not None:
            return (*self.completion_dirs, str(self.completion_models_of(cell)))
        return self.completion_dirs


@dataclass(frozen=True)
class LaunchPlan:
    cell_spec: LocalCellSpec
    layout: CellLayout
    container: ContainerSpec
    timeout_seconds: int
    grace_seconds: float


def container_name(job_uid: str) -> str:
    """One container name per job: the engine refuses a second one, so a job never runs twice."""
    return f"armnet-{job_uid}"


def cell_spec_for(cell: Cell) -> LocalCellSpec:
    """The simulated cell the connector serves for ``cell`` (its arms, limits, cameras, grace)."""
    preset = EMBODIMENT_PRESET.get(cell.embodiment)
    if preset is None:
        raise LaunchError(
            f"cell {cell.name}: embodiment {cell.embodiment!r} has no simulator; "
            f"simulated cells support {sorted(EMBODIMENT_PRESET)}"
        )
    first = next(iter(cell.arms.values()))
    limits = {arm.safety_limit for arm in cell.arms.values() if arm.safety_limit is not None}
    return LocalCellSpec(
        preset=preset,
        embodiment=cell.embodiment,
        task=cell.task or "default",
        robot_id=(first.robot_id or cell.name) if preset == "so101" else _bimanual_id(cell),
        safety_limit=min(limits) if limits else DEFAULT_SAFETY_LIMIT,
        safety_policy=cell.safety_policy,
        allow_calibration_jobs=cell.allow_calibration_jobs,
        register_bounds=cell.register_bounds,
        completion=cell.completion,
        reset=cell.reset,
        cameras=cell.cameras,
        grace_seconds=cell.grace_seconds,
        reset_timeout_seconds=cell.reset_timeout_seconds,
        language_instruction=cell.language_instruction,
        cell_name=cell.name,
    )


def _bimanual_id(cell: Cell) -> str:
    """LeRobot names bimanual calibration files ``<id>_left``/``<id>_right``: the shared stem."""
    left = cell.arms.get("left")
    if left is not None and left.robot_id and left.robot_id.endswith("_left"):
        return left.robot_id[: -len("_left")]
    return cell.name


def completion_files_refused(cell: Cell, paths: HostPaths) -> str | None:
    """Why a new job must not launch on ``cell``: its monitor names a file outside the agent's directories,
    or a model from a ConfigMap the agent could not write to a file (``completion_configmap``).

    Asked before a launch only, never of a job the agent adopts (it runs already: a change
    of the directories must not fail it mid-run). The heartbeat's ``CompletionReady`` says
    the same earlier, so the operator does not bind such a cell; this closes the window of
    a Cell edited between the binding and the launch.
    """
    classifier = cell.completion.classifier if cell.completion is not None else None
    if classifier is not None and classifier.model_from is not None:
        ref = classifier.model_from.config_map_key_ref
        return f"cell {cell.name}: its classifier's model (ConfigMap {ref.name}, key {ref.key}) is not on this host"
    refused = outside_dirs(host_files(cell.completion), paths.completion_dirs_for(cell.completion, cell.name))
    return f"cell {cell.name}: {refused}" if refused is not None else None


def plan_launch(job: Job, cell: Cell, paths: HostPaths, secrets: Mapping[str, str]) -> LaunchPlan:
    """Everything the launch of ``job`` on ``cell`` does; ``secrets`` are env name -> value."""
    if not cell.simulated:
        raise LaunchError(
            f"cell {cell.name} is not simulated; this agent runs simulated cells only so far "
            "(set spec.simulated: true)"
        )
    spec = cell_spec_for(cell)
    run_dir = paths.run_dir(job.uid)
    layout = replace(
        plan_layout(spec, run_dir), cache_dir=paths.cache_dir(cell.name), volume_dir=paths.volume_dir(job.namespace),
        output_dir=paths.output_dir(job.uid), record_dir=paths.record_dir(job.uid),
    )
    env = build_job_env(spec, layout, job_id=job.uid, timeout_seconds=job.timeout_seconds, args=job.args)
    env.update(secrets)
    if secrets:
        env[env_keys.SECRETS] = json.dumps(sorted(secrets))
    env["PYTHONUNBUFFERED"] = "1"
    env.update(paths.dev_env or {})
    too_big = oversized_env(env)
    if too_big:
        raise LaunchError(
            f"the job's env var(s) {', '.join(too_big)} exceed the kernel's 128 KiB limit per variable; "
            "pass large inputs through the volume or a download instead of spec.args"
        )
    mounts = (
        Mount(str(layout.socket_dir), str(layout.socket_dir)),
        Mount(str(layout.calibration_dir), str(layout.calibration_dir), read_only=True),
        Mount(str(layout.cache_dir), str(layout.cache_dir)),
        Mount(str(layout.volume_dir), str(layout.volume_dir)),
        Mount(str(layout.output_dir), str(layout.output_dir)),
        *(Mount(path, path, read_only=True) for path in paths.dev_mounts),
    )
    container = ContainerSpec(
        image=job.image,
        env=env,
        mounts=mounts,
        labels=job_labels(job, cell.name),
        name=container_name(job.uid),
    )
    return LaunchPlan(spec, layout, container, job.timeout_seconds, cell.grace_seconds)


def job_labels(job: Job, cell: str) -> dict[str, str]:
    """Identity only: never a secret, never the args."""
    return {
        LABEL_MANAGED_BY: MANAGED_BY_AGENT,
        LABEL_CELL: cell,
        LABEL_JOB_UID: job.uid,
        LABEL_NAMESPACE: job.namespace,
        LABEL_NAME: job.name,
    }

"""What a simulated cell looks like, and the env a job on it receives.

Shared by local runs (from flags and a cell file) and the node agent (from a
Cell's spec, see ``armnet_node.plan``).

Pure: from flags and an optional cell file it derives a frozen
:class:`LocalCellSpec`, the per-arm layout (robot ids, calibration files,
endpoints), the ``ARMNET_CELL_CONFIG`` document and the job's env vars. No
files are written and no process is started here (see ``session``).

The default cell matches a real SO-101 cell: one arm with a calibration file
and a ``robot_id``, a safety limit, and one camera ``front`` (640x480, 30 fps).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from armnet_core import BIMANUAL_SO101_EMBODIMENT, SO101_EMBODIMENT
from armnet_core.cell_completion import CompletionConfig, ResetConfig, reset_problem, unknown_camera
from armnet_runtime import env as env_keys
from armnet_runtime.endpoints import OPERATOR_SOCKET, ROBOT_SOCKET, with_arm
from pydantic import BaseModel, ConfigDict, Field, ValidationError

PRESET_EMBODIMENT = {"so101": SO101_EMBODIMENT, "bimanual_so101": BIMANUAL_SO101_EMBODIMENT}
EMBODIMENT_PRESET = {embodiment: preset for preset, embodiment in PRESET_EMBODIMENT.items()}
PRESET_ARMS = {"so101": ("arm",), "bimanual_so101": ("left", "right")}

DEFAULT_TASK = "default"
DEFAULT_ROBOT_ID = "so101-sim"
#: Degrees per goal write (LeRobot max_relative_target) on the default cell.
DEFAULT_SAFETY_LIMIT = 10.0
DEFAULT_GRACE_SECONDS = 10.0
DEFAULT_RESET_TIMEOUT_SECONDS = 60.0
#: LeRobot's dataset root under the job's output directory.
LEROBOT_DIR = "lerobot"


class LocalCellError(ValueError):
    """The flags or the cell file describe a cell we cannot build; the message says what to fix."""


class CameraFile(BaseModel):
    model_config = ConfigDict(extra="forbid")
    width: int = Field(default=640, gt=0)
    height: int = Field(default=480, gt=0)
    fps: int = Field(default=30, gt=0)


class LocalCellFile(BaseModel):
    """The ``--cell-config`` file (JSON or YAML): every field optional, flags win."""

    model_config = ConfigDict(extra="forbid")
    preset: Literal["so101", "bimanual_so101"] | None = None
    task: str | None = None
    robot_id: str | None = None
    safety_limit: float | None = Field(default=None, gt=0, allow_inf_nan=False)
    safety_policy: Literal["clamp", "trip"] = "clamp"
    allow_calibration_jobs: bool = False
    cameras: dict[str, CameraFile] | None = None
    grace_period_seconds: float | None = Field(default=None, ge=0)
    reset_timeout_seconds: float | None = Field(default=None, gt=0)
    language_instruction: str | None = None
    latency_ms: float = Field(default=0.0, ge=0)
    completion: CompletionConfig | None = Field(
        default=None, description="the cell's completion monitor (docs/connector.md); None: operators only"
    )
    calibration_files: dict[str, Path] = Field(
        default_factory=dict, description="arm name -> LeRobot calibration JSON (default: shipped)"
    )
    reset: ResetConfig | None = Field(
        default=None, description="how ctx.cell.reset() puts the workspace back (docs/connector.md); None: a person"
    )


@dataclass(frozen=True)
class CameraSpec:
    """One camera of a cell, as a local run and the node agent's Cell both describe it."""

    name: str
    width: int = 640
    height: int = 480
    fps: int = 30
    #: The device (an index or a path) on the cell's host; None on a simulated cell,
    #: where the simulator serves each camera by its name.
    index_or_path: int | str | None = None


@dataclass(frozen=True)
class LocalCellSpec:
    preset: str
    embodiment: str
    task: str
    robot_id: str = DEFAULT_ROBOT_ID
    safety_limit: float = DEFAULT_SAFETY_LIMIT
    safety_policy: str = "clamp"
    allow_calibration_jobs: bool = False
    #: Raw [low, high] bounds per servo register, over the connector's defaults (docs/connector.md).
    register_bounds: Mapping[str, tuple[int, int]] = field(default_factory=dict)
    cameras: tuple[CameraSpec, ...] = (CameraSpec("front"),)
    grace_seconds: float = DEFAULT_GRACE_SECONDS
    reset_timeout_seconds: float = DEFAULT_RESET_TIMEOUT_SECONDS
    language_instruction: str | None = None
    latency_ms: float = 0.0
    calibration_files: Mapping[str, Path] = field(default_factory=dict)
    #: The Cell's name on a cluster (None: a local run's ``local-<preset>``).
    cell_name: str | None = None
    #: The cell's completion monitor (None: only an operator's outcome completes an episode).
    completion: CompletionConfig | None = None
    #: How ``ctx.cell.reset()`` puts the workspace back (None: a person confirms).
    reset: ResetConfig | None = None

    @property
    def arm_names(self) -> tuple[str, ...]:
        return PRESET_ARMS[self.preset]

    @property
    def is_bimanual(self) -> bool:
        return len(self.arm_names) > 1


@dataclass(frozen=True)
class ArmLayout:
    """Where one arm's identity lives on disk and on the socket."""

    name: str
    robot_id: str
    calibration_file: Path
    endpoint: str


@dataclass(frozen=True)
class CellLayout:
    socket_dir: Path
    calibration_dir: Path
    cache_dir: Path
    volume_dir: Path
    arms: tuple[ArmLayout, ...]
    #: The job's own output directory (``ARMNET_OUTPUT_DIR``); the agent uploads it when the job ends.
    output_dir: Path
    #: The cell's record of the job (the rollouts' pictures): never mounted into the job's container;
    #: the node agent uploads it with the output under ``armnet-cell/``. None: not kept (``armnet run``).
    record_dir: Path | None = None

    @property
    def robot_endpoint(self) -> str:
        return f"unix://{self.socket_dir / ROBOT_SOCKET}"

    @property
    def operator_endpoint(self) -> str:
        return f"unix://{self.socket_dir / OPERATOR_SOCKET}"


def load_cell_file(path: str | Path) -> LocalCellFile:
    """Read a ``--cell-config`` file; a bad one is a :class:`LocalCellError` naming the field."""
    source = Path(path)
    try:
        text = source.read_text()
    except OSError as exc:
        raise LocalCellError(f"cannot read the cell config {source}: {exc.strerror}") from exc
    try:
        if source.suffix in (".yaml", ".yml"):
            import yaml

            data = yaml.safe_load(text)
        else:
            data = json.loads(text)
        return LocalCellFile.model_validate(data)
    except (ValueError, ValidationError) as exc:
        raise LocalCellError(f"the cell config {source} is invalid: {exc}") from exc


def resolve_spec(
    *,
    embodiment: str | None,
    preset: str | None,
    task: str | None,
    grace_seconds: float | None,
    cell_file: LocalCellFile | None = None,
) -> LocalCellSpec:
    """Merge defaults, the cell file and the flags (in that order of precedence, flags last)."""
    file = cell_file or LocalCellFile()
    chosen_preset = preset or file.preset
    if chosen_preset is None and embodiment is not None:
        chosen_preset = EMBODIMENT_PRESET.get(embodiment)
        if chosen_preset is None:
            raise LocalCellError(
                f"no simulated cell for embodiment {embodiment!r}; local runs support "
                f"{sorted(EMBODIMENT_PRESET)}"
            )
    chosen_preset = chosen_preset or "so101"
    if chosen_preset not in PRESET_EMBODIMENT:
        raise LocalCellError(f"unknown preset {chosen_preset!r}; choose one of {sorted(PRESET_EMBODIMENT)}")
    cell_embodiment = PRESET_EMBODIMENT[chosen_preset]
    if embodiment is not None and embodiment != cell_embodiment:
        raise LocalCellError(
            f"embodiment {embodiment!r} does not match the {chosen_preset!r} cell "
            f"({cell_embodiment!r}); drop --preset or pass --embodiment {cell_embodiment}"
        )
    unknown_arms = set(file.calibration_files) - set(PRESET_ARMS[chosen_preset])
    if unknown_arms:
        raise LocalCellError(
            f"calibration_files names arm(s) {sorted(unknown_arms)}, but the {chosen_preset!r} "
            f"cell has {list(PRESET_ARMS[chosen_preset])}"
        )
    cameras = (
        tuple(CameraSpec(name, c.width, c.height, c.fps) for name, c in file.cameras.items())
        if file.cameras is not None
        else (CameraSpec("front"),)
    )
    problem = unknown_camera(file.completion, {camera.name for camera in cameras}) or reset_problem(
        file.reset, file.completion, PRESET_ARMS[chosen_preset])
    classifier = file.completion.classifier if file.completion is not None else None
    if problem is None and classifier is not None and classifier.model_from is not None:
        problem = ("completion.classifier.modelFrom names a ConfigMap, which only a node agent in a cluster reads; "
                   "a local run's cell file gives completion.classifier.model, the .onnx file's path")
    if problem is not None:
        raise LocalCellError(problem)
    return LocalCellSpec(
        preset=chosen_preset,
        embodiment=cell_embodiment,
        task=task or file.task or DEFAULT_TASK,
        robot_id=file.robot_id or DEFAULT_ROBOT_ID,
        safety_limit=file.safety_limit or DEFAULT_SAFETY_LIMIT,
        safety_policy=file.safety_policy,
        allow_calibration_jobs=file.allow_calibration_jobs,
        cameras=cameras,
        grace_seconds=(
            grace_seconds
            if grace_seconds is not None
            else file.grace_period_seconds
            if file.grace_period_seconds is not None
            else DEFAULT_GRACE_SECONDS
        ),
        reset_timeout_seconds=file.reset_timeout_seconds or DEFAULT_RESET_TIMEOUT_SECONDS,
        language_instruction=file.language_instruction,
        latency_ms=file.latency_ms,
        calibration_files=dict(file.calibration_files),
        completion=file.completion,
        reset=file.reset,
    )


def plan_layout(spec: LocalCellSpec, run_dir: Path) -> CellLayout:
    """The directory layout of one local run under ``run_dir`` (nothing is created here).

    Bimanual arms follow LeRobot's id convention (``<robot_id>_left``), so
    ``ctx.cell.prepare_bimanual_calibration_dir()`` finds the files by name.
    """
    socket_dir = run_dir / "sockets"
    calibration_dir = run_dir / "calibration"
    robot_endpoint = f"unix://{socket_dir / ROBOT_SOCKET}"
    arms = []
    for name in spec.arm_names:
        robot_id = spec.robot_id if not spec.is_bimanual else f"{spec.robot_id}_{name}"
        endpoint = with_arm(robot_endpoint, name) if spec.is_bimanual else robot_endpoint
        arms.append(ArmLayout(name, robot_id, calibration_dir / f"{robot_id}.json", endpoint))
    return CellLayout(
        socket_dir=socket_dir,
        calibration_dir=calibration_dir,
        cache_dir=run_dir / "cache",
        volume_dir=run_dir / "volume",
        arms=tuple(arms),
        output_dir=run_dir / "output",
    )


def build_cell_config(spec: LocalCellSpec, layout: CellLayout) -> dict[str, Any]:
    """The ``ARMNET_CELL_CONFIG`` document a real cell of this shape would inject."""
    document: dict[str, Any] = {
        "cell_name": spec.cell_name or f"local-{spec.preset}",
        "embodiment": spec.embodiment,
        "task": spec.task,
        "robot_connector_endpoint": layout.robot_endpoint,
        "operator_call_endpoint": layout.operator_endpoint,
        "robot_id": spec.robot_id,
        "calibration_dir": str(layout.calibration_dir),
        "safety_limit": spec.safety_limit,
        "camera_configs": {
            camera.name: {
                "index_or_path": camera.name,
                "fps": camera.fps,
                "width": camera.width,
                "height": camera.height,
            }
            for camera in spec.cameras
        },
    }
    if spec.language_instruction is not None:
        document["language_instruction"] = spec.language_instruction
    if spec.is_bimanual:
        document["arms"] = {
            arm.name: {
                "robot_port": arm.endpoint,
                "robot_id": arm.robot_id,
                "calibration_dir": str(layout.calibration_dir),
                "calibration_file_path": str(arm.calibration_file),
                "safety_limit": spec.safety_limit,
            }
            for arm in layout.arms
        }
    else:
        document["calibration_file_path"] = str(layout.arms[0].calibration_file)
    return document


def build_job_env(
    spec: LocalCellSpec,
    layout: CellLayout,
    *,
    job_id: str,
    timeout_seconds: int,
    args: Mapping[str, Any],
) -> dict[str, str]:
    """Exactly the env vars a cell injects into the job (nothing of the host's)."""
    env = {
        env_keys.JOB_ID: job_id,
        env_keys.EMBODIMENT: spec.embodiment,
        env_keys.TASK: spec.task,
        env_keys.TIMEOUT_SECONDS: str(timeout_seconds),
        env_keys.ARGS: json.dumps(dict(args), separators=(",", ":")),
        env_keys.CELL_CONFIG: json.dumps(build_cell_config(spec, layout), separators=(",", ":")),
        env_keys.CELL_SOCKET: layout.robot_endpoint,
        env_keys.OPERATOR_CALL_ENDPOINT: layout.operator_endpoint,
        env_keys.ROBOT_ID: spec.robot_id,
        env_keys.CALIBRATION_DIR: str(layout.calibration_dir),
        env_keys.CACHE_HOME: str(layout.cache_dir),
        env_keys.VOLUME_HOME: str(layout.volume_dir),
        env_keys.HF_HOME: str(layout.cache_dir / "huggingface"),
        env_keys.OUTPUT_DIR: str(layout.output_dir),
        # LeRobot's datasets (``LeRobotDataset.create``, ``lerobot-record``) land in the output directory.
        env_keys.HF_LEROBOT_HOME: str(layout.output_dir / LEROBOT_DIR),
        # LeRobot's own commands started in the job reach the cell through the connector, and the
        # cell-owned ones (lerobot-calibrate unless the cell allows it) are refused at once.
        env_keys.LEROBOT_TOOLS: "remote",
        env_keys.CALIBRATION_JOBS: "1" if spec.allow_calibration_jobs else "0",
    }
    if not spec.is_bimanual:
        env[env_keys.CALIBRATION_FILE_PATH] = str(layout.arms[0].calibration_file)
    return env

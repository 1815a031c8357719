"""The ``ARMNET_CELL_CONFIG`` document: the cell's settings as the job sees them.

The agent writes this JSON into the job's environment; :func:`parse_cell_config`
turns it into a validated, frozen model. Unknown or malformed fields are refused
with a message that names the field (``arms.left.robot_port: ...``), because a
silently ignored typo in a safety limit is worse than a job that does not start.
This module never opens sockets or files.

Shape (every field optional)::

    {
      "cell_name": "cell-a", "embodiment": "lerobot/so-101", "task": "pick",
      "robot_connector_endpoint": "unix:///run/armnet/robot.sock",
      "connector_socket_path": "/run/armnet/robot.sock",
      "robot_port": "/dev/ttyACM0",
      "operator_call_endpoint": "unix:///run/armnet/operator.sock",
      "robot_id": "so101-a",
      "calibration_dir": "/calibration", "calibration_file_path": "/calibration/so101-a.json",
      "language_instruction": "pick up the cube",
      "safety_limit": 10.0
          | {"lerobot/so-101": 10.0, "lerobot/bimanual_so101": {"left": 8.0, "right": 9.0}}
          | {"left": 8.0, "right": 9.0},
      "arms": {"left": {"robot_port": "...", "robot_id": "...", "calibration_dir": "...",
                         "calibration_file_path": "...", "safety_limit": 8.0}},
      "camera_configs": {"front": {"index_or_path": 0, "fps": 30, "width": 640, "height": 480,
                                   "color_mode": "rgb", "rotation": 0, "warmup_s": 1}}
    }
"""

from __future__ import annotations

import json
import sys
from collections.abc import Iterator
from typing import Any, Literal, Optional, Union

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

SafetyLimitValue = Union[float, dict[str, Union[float, dict[str, float]]]]


class CellConfigError(ValueError):
    """``ARMNET_CELL_CONFIG`` is not valid JSON or does not match the documented shape."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class ArmConfig(_Strict):
    """One named arm of a multi-arm cell."""

    robot_port: Optional[str] = None
    robot_id: Optional[str] = None
    calibration_dir: Optional[str] = None
    calibration_file_path: Optional[str] = None
    safety_limit: Optional[float] = Field(default=None, gt=0)


class CameraConfig(_Strict):
    """OpenCV camera settings, field for field LeRobot's ``OpenCVCameraConfig``."""

    index_or_path: Union[int, str]
    fps: Optional[int] = Field(default=None, gt=0)
    width: Optional[int] = Field(default=None, gt=0)
    height: Optional[int] = Field(default=None, gt=0)
    color_mode: Literal["rgb", "bgr"] = "rgb"
    rotation: Literal[0, 90, 180, 270, -90] = 0
    warmup_s: int = Field(default=1, ge=0)
    fourcc: Optional[str] = Field(default=None, min_length=4, max_length=4)


class CellConfig(_Strict):
    """The validated ``ARMNET_CELL_CONFIG`` document."""

    cell_name: Optional[str] = None
    embodiment: Optional[str] = None
    task: Optional[str] = None
    robot_connector_endpoint: Optional[str] = None
    connector_socket_path: Optional[str] = None
    robot_port: Optional[str] = None
    operator_call_endpoint: Optional[str] = None
    robot_id: Optional[str] = None
    calibration_dir: Optional[str] = None
    calibration_file_path: Optional[str] = None
    language_instruction: Optional[str] = None
    safety_limit: Optional[SafetyLimitValue] = None
    arms: dict[str, ArmConfig] = Field(default_factory=dict)
    camera_configs: dict[str, CameraConfig] = Field(default_factory=dict)

    @field_validator("safety_limit")
    @classmethod
    def _limits_positive(cls, value: Optional[SafetyLimitValue]) -> Optional[SafetyLimitValue]:
        for where, number in _flatten_limits(value, "safety_limit"):
            if not number > 0:
                raise ValueError(f"{where} must be a positive number, got {number!r}")
        return value

    def cell_safety_limit(self, embodiment: str) -> Optional[float]:
        """The cell-wide limit: the number, or the number given for ``embodiment``."""
        limit = self.safety_limit
        if isinstance(limit, dict):
            chosen = limit.get(embodiment)
            return float(chosen) if isinstance(chosen, (int, float)) else None
        return None if limit is None else float(limit)

    def arm_safety_limit(self, arm: str, embodiment: str) -> Optional[float]:
        """An arm's limit: its own, else per-embodiment-per-arm, else per-arm, else the cell's."""
        own = self.arms[arm].safety_limit if arm in self.arms else None
        if own is not None:
            return own
        limit = self.safety_limit
        if isinstance(limit, dict):
            for_embodiment = limit.get(embodiment)
            if isinstance(for_embodiment, dict) and arm in for_embodiment:
                return float(for_embodiment[arm])
            for_arm = limit.get(arm)
            if isinstance(for_arm, (int, float)):
                return float(for_arm)
        return self.cell_safety_limit(embodiment)


def _flatten_limits(value: Any, where: str) -> list[tuple[str, float]]:
    if value is None:
        return []
    if isinstance(value, dict):
        found: list[tuple[str, float]] = []
        for key, item in value.items():
            found.extend(_flatten_limits(item, f"{where}.{key}"))
        return found
    return [(where, float(value))]


def _describe_error(error: Any) -> str:
    location = ".".join(str(part) for part in error.get("loc", ()) if not _is_union_tag(part))
    if error.get("type") == "extra_forbidden":
        return f"{location}: unknown field (check its spelling against the documented fields)"
    return f"{location or '<document>'}: {error.get('msg')}"


def _is_union_tag(part: Any) -> bool:
    # pydantic puts the tried union member ("float", "dict[str,...]") into the location.
    return isinstance(part, str) and ("[" in part or part in {"float", "int", "str"})


def parse_cell_config(raw: str) -> CellConfig:
    """Parse and validate the ``ARMNET_CELL_CONFIG`` JSON text.

    Raises :class:`CellConfigError` naming every bad field.
    """
    try:
        document = json.loads(raw)
    except json.JSONDecodeError as exc:
        raise CellConfigError(f"ARMNET_CELL_CONFIG is not valid JSON: {exc}") from exc
    if not isinstance(document, dict):
        raise CellConfigError(
            f"ARMNET_CELL_CONFIG must be a JSON object, got {type(document).__name__}"
        )
    try:
        return CellConfig.model_validate(document)
    except ValidationError as exc:
        problems = sorted({_describe_error(error) for error in exc.errors()})
        raise CellConfigError("ARMNET_CELL_CONFIG is invalid: " + "; ".join(problems)) from exc


def build_camera_configs(cameras: dict[str, CameraConfig]) -> dict[str, Any]:
    """The cell's cameras as LeRobot ``OpenCVCameraConfig`` objects, or plain dicts.

    Why not import LeRobot here: this runs before ``@main``, and LeRobot's camera
    module brings torch (seconds of CPU) into every job. The mapping holds plain dicts
    and becomes LeRobot's configs, in place, the first time a value is read once the job
    has imported LeRobot (``SO101FollowerConfig(cameras=ctx.camera_configs)`` reads them);
    a job that never imports LeRobot never loads it. Without LeRobot installed they stay
    plain dicts.
    """
    return CameraConfigs(cameras)


class CameraConfigs(dict[str, Any]):
    """A dict of camera configs that turns into LeRobot's the first time it is read after
    the job imported LeRobot. Every read goes through here (``__iter__`` is overridden, so
    ``dict(...)`` and ``{**...}`` take the slow path through ``__getitem__`` too)."""

    def __init__(self, cameras: Any = ()) -> None:
        given = dict(cameras)
        if all(isinstance(camera, CameraConfig) for camera in given.values()):
            super().__init__({name: camera.model_dump() for name, camera in given.items()})
            self._cameras: dict[str, CameraConfig] = given
        else:  # built like a dict from ready values (dataclasses.asdict, copies): kept as given
            super().__init__(given)
            self._cameras = {}
        self._upgraded = not self._cameras

    def _upgrade(self) -> None:
        if self._upgraded or "lerobot" not in sys.modules:
            return
        self._upgraded = True
        try:
            configs = _lerobot_camera_configs(self._cameras)
        except ImportError:
            return
        super().update(configs)

    def __getitem__(self, key: str) -> Any:
        self._upgrade()
        return super().__getitem__(key)

    def get(self, key: str, default: Any = None) -> Any:
        self._upgrade()
        return super().get(key, default)

    def __iter__(self) -> Iterator[str]:
        self._upgrade()
        return super().__iter__()

    def items(self) -> Any:
        self._upgrade()
        return super().items()

    def values(self) -> Any:
        self._upgrade()
        return super().values()

    def __repr__(self) -> str:
        self._upgrade()
        return super().__repr__()


def _lerobot_camera_configs(cameras: dict[str, CameraConfig]) -> dict[str, Any]:
    from lerobot.cameras.configs import ColorMode, Cv2Rotation
    from lerobot.cameras.opencv import OpenCVCameraConfig

    built: dict[str, Any] = {}
    for name, camera in cameras.items():
        rotation = -90 if camera.rotation == 270 else camera.rotation
        kwargs: dict[str, Any] = {
            "index_or_path": camera.index_or_path,
            "fps": camera.fps,
            "width": camera.width,
            "height": camera.height,
            "color_mode": ColorMode(camera.color_mode),
            "rotation": Cv2Rotation(rotation),
            "warmup_s": camera.warmup_s,
        }
        if camera.fourcc is not None:
            kwargs["fourcc"] = camera.fourcc
        built[name] = OpenCVCameraConfig(**kwargs)
    return built

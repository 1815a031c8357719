"""The cell as the connector sees it: arms, cameras, limits and the job's clocks.

This module owns the connector's configuration model (pydantic, the boundary
with files and with ``armnet run``) and the calibration file reader. It never
opens a device.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from armnet_core.cell_completion import CompletionConfig, ResetConfig, reset_problem, unknown_camera
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator
from pydantic.alias_generators import to_camel

from .identity import NORM_MODES
from .registers import valid_bounds

#: LeRobot's motor model for every SO-101 joint.
DEFAULT_MOTOR_MODEL = "sts3215"


class _Model(BaseModel):
    # camelCase keys (as in the Cell CRD) and snake_case (as in Python) both load.
    model_config = ConfigDict(alias_generator=to_camel, populate_by_name=True, extra="forbid")


class ArmConfig(_Model):
    """One arm of the cell: the device the customer's ``port`` is mapped to, and its limits."""

    port: str = Field(description="device path of the arm's servo bus on this host, e.g. /dev/ttyACM0")
    calibration_file: Path | None = Field(
        default=None, description="LeRobot calibration JSON of this arm (absolute limits, rest pose)"
    )
    robot_id: str | None = None
    safety_limit: float | dict[str, float] | None = Field(
        default=None,
        description="LeRobot max_relative_target: largest step from the present position per "
        "goal write, in the units of the write (one number for all motors, or per motor)",
    )
    rest_pose: dict[str, int] | None = Field(
        default=None, description="raw servo ticks per motor; default: the middle of each calibrated range"
    )
    motor_model: str = DEFAULT_MOTOR_MODEL
    norm_modes: dict[str, str] | None = Field(
        default=None,
        description="LeRobot MotorNormMode value per motor (degrees, range_0_100, range_m100_100); "
        "default: the SO-101's (body in degrees, gripper range_0_100). A job must declare the same.",
    )

    @field_validator("safety_limit", mode="before")
    @classmethod
    def _valid_limit(cls, value: Any) -> Any:
        return check_limit(value, "safetyLimit")

    @field_validator("norm_modes")
    @classmethod
    def _known_norm_modes(cls, value: dict[str, str] | None) -> dict[str, str] | None:
        for motor, mode in (value or {}).items():
            if mode not in NORM_MODES:
                raise ValueError(f"normModes[{motor!r}] is {mode!r}; use one of {sorted(NORM_MODES)}")
        return value


def check_limit(value: Any, what: str) -> Any:
    """A relative limit as LeRobot's ``max_relative_target`` takes it, or a readable error.

    Why strict: NaN compares false with everything (so every step would pass), a
    negative or zero limit refuses every move, and a string or bool is a typo
    that must not silently become a number.
    """
    if value is None:
        return None
    if isinstance(value, dict):
        if not value:
            raise ValueError(f"{what} is an empty mapping; give a number per motor, one number, or null")
        for motor, limit in value.items():
            if not isinstance(motor, str):
                raise ValueError(f"{what} keys must be motor names, got {motor!r}")
            check_limit(limit, f"{what}[{motor!r}]")
        return value
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(
            f"{what} must be a number of units per write (or a mapping motor -> number), "
            f"got {type(value).__name__} {str(value)[:40]!r}"
        )
    if not math.isfinite(value):
        raise ValueError(f"{what} is {value}; it must be a finite number (NaN would let every step pass)")
    if value <= 0:
        raise ValueError(f"{what} is {value}; it must be positive (or null for no relative limit)")
    return value


class CameraConfig(_Model):
    """One camera of the cell, as OpenCV settings (the device side of ``OpenCVCameraConfig``)."""

    index_or_path: int | str
    fps: int | None = None
    width: int | None = None
    height: int | None = None
    color_mode: str = "rgb"
    rotation: int = 0
    warmup_s: int = 1
    fourcc: str | None = None


class ConnectorConfig(_Model):
    """Everything the connector needs to serve one job on one cell."""

    arms: dict[str, ArmConfig]
    default_arm: str | None = Field(
        default=None, description="arm served when the customer's endpoint has no ?arm= (default: the only arm)"
    )
    cameras: dict[str, CameraConfig] = Field(default_factory=dict)
    simulated: bool = False
    max_connections: int = Field(
        default=64, ge=1, le=4096, description="connections each socket serves at once; more are refused"
    )
    timeout_seconds: float | None = Field(default=None, gt=0, description="job deadline; null: none")
    clock_starts_with_job: bool = Field(
        default=False,
        description="start the deadline when the job starts (its first connection, or the agent's job_started "
        "notice), not when the connector starts: a pod's sidecar is up before the job's container, whose "
        "image may still be pulled",
    )
    grace_period_seconds: float = Field(default=10.0, ge=0)
    reset_timeout_seconds: float = Field(default=300.0, gt=0)
    disable_torque_on_shutdown: bool = True
    rest_on_shutdown: bool = Field(
        default=False, description="at the job's end (stop, SIGTERM), return every arm to rest before torque off"
    )
    rest_speed_ticks_per_second: float = Field(
        default=600.0, gt=0, description="speed limit of return_to_rest, in raw servo ticks per second"
    )
    safety_policy: Literal["clamp", "trip"] = Field(
        default="clamp",
        description="goals beyond the relative limit: clamped to present ± limit as LeRobot's "
        "max_relative_target does (clamp), or refused with the interlock tripped (trip)",
    )
    allow_calibration_jobs: bool = Field(
        default=False,
        description="let jobs run LeRobot's calibration (EEPROM writes of homing and limits); off: "
        "the calibration belongs to the cell and is read-only",
    )
    register_bounds: dict[str, tuple[int, int]] = Field(
        default_factory=dict,
        description="inclusive [low, high] raw bounds per bounded register (registers.DEFAULT_BOUNDS)",
    )
    completion: CompletionConfig | None = Field(
        default=None,
        description="the cell's completion monitor: which camera it watches and how it scores "
        "(None: no monitor, every episode waits for an operator's outcome)",
    )
    reset: ResetConfig | None = Field(
        default=None,
        description="how ctx.cell.reset() puts the workspace back: an operator's confirmation (None, Operator), "
        "or scripted poses judged by the completion monitor (Scripted)",
    )
    present_position_max_age_ms: float = Field(
        default=25.0,
        ge=0,
        description="a Present_Position sync_read younger than this is reused by the safety check "
        "instead of reading the bus again (0: always read)",
    )

    @model_validator(mode="after")
    def _check_arms(self) -> ConnectorConfig:
        if not self.arms:
            raise ValueError("a cell needs at least one arm under 'arms'")
        if self.default_arm is not None and self.default_arm not in self.arms:
            raise ValueError(f"default_arm {self.default_arm!r} is not one of the arms {sorted(self.arms)}")
        problems = valid_bounds(self.register_bounds)
        if problems:
            raise ValueError("registerBounds: " + "; ".join(problems))
        camera_problem = unknown_camera(self.completion, self.cameras)
        if camera_problem is not None:
            raise ValueError(camera_problem)
        reset = reset_problem(self.reset, self.completion, self.arms)
        if reset is not None:
            raise ValueError(reset)
        return self

    def arm_for(self, selector: str | None) -> tuple[str, ArmConfig]:
        """The arm a customer's endpoint selects; ``KeyError`` with a readable message if none."""
        if selector is None:
            name = self.default_arm or (next(iter(self.arms)) if len(self.arms) == 1 else None)
            if name is None:
                raise KeyError(
                    f"this cell has several arms {sorted(self.arms)}: select one with ?arm=NAME "
                    "in the port (ctx.arm(NAME).port does this)"
                )
            return name, self.arms[name]
        if selector not in self.arms:
            raise KeyError(f"this cell has no arm {selector!r}; its arms are {sorted(self.arms)}")
        return selector, self.arms[selector]


def load_config(path: str | Path) -> ConnectorConfig:
    """Read a ``ConnectorConfig`` from a JSON or YAML file."""
    text = Path(path).read_text()
    data: Any
    if str(path).endswith((".yaml", ".yml")):
        import yaml

        data = yaml.safe_load(text)
    else:
        data = json.loads(text)
    return ConnectorConfig.model_validate(data)


@dataclass(frozen=True)
class MotorRange:
    """The calibrated facts of one motor that safety and rest need (raw servo ticks)."""

    id: int
    range_min: int
    range_max: int
    drive_mode: int = 0
    homing_offset: int = 0

    @property
    def middle(self) -> int:
        return (self.range_min + self.range_max) // 2


def read_calibration_file(path: Path) -> dict[str, MotorRange]:
    """Parse a LeRobot calibration JSON (``{motor: {id, drive_mode, homing_offset, range_min, range_max}}``)."""
    data = json.loads(Path(path).read_text())
    if not isinstance(data, dict):
        raise ValueError(f"calibration file {path} must hold a JSON object keyed by motor name")
    ranges: dict[str, MotorRange] = {}
    for motor, entry in data.items():
        try:
            ranges[motor] = MotorRange(
                id=int(entry["id"]),
                range_min=int(entry["range_min"]),
                range_max=int(entry["range_max"]),
                drive_mode=int(entry.get("drive_mode", 0)),
                homing_offset=int(entry.get("homing_offset", 0)),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"calibration file {path}: motor {motor!r} is malformed ({exc})") from exc
    return ranges

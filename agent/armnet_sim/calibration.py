"""LeRobot calibration files: read, write, and the ones shipped for simulated arms.

The file format is LeRobot's (``draccus.dump(dict[str, MotorCalibration])``):
one object per motor with ``id``, ``drive_mode``, ``homing_offset``,
``range_min`` and ``range_max``. The simulator seeds servo EEPROM from such a
file, so the real ``FeetechMotorsBus.is_calibrated`` holds and LeRobot never
falls back to its interactive ``input()`` calibration.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from importlib import resources
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from .servo import ServoCalibration


class CalibrationError(ValueError):
    """A calibration file is missing, malformed, or has impossible values."""


@dataclass(frozen=True)
class MotorCalibration:
    """One motor's entry, field for field as LeRobot's ``MotorCalibration``."""

    id: int
    drive_mode: int
    homing_offset: int
    range_min: int
    range_max: int

    def servo_calibration(self) -> ServoCalibration:
        return ServoCalibration(self.homing_offset, self.range_min, self.range_max)


class _Entry(BaseModel):
    model_config = ConfigDict(extra="forbid")

    id: int = Field(ge=0, le=252)
    drive_mode: int = Field(ge=0, le=1)
    homing_offset: int = Field(ge=-2047, le=2047)  # sign-magnitude, sign bit 11
    range_min: int = Field(ge=0, le=4095)
    range_max: int = Field(ge=0, le=4095)

    @model_validator(mode="after")
    def _ordered(self) -> _Entry:
        if self.range_min >= self.range_max:
            raise ValueError(f"range_min {self.range_min} must be below range_max {self.range_max}")
        return self


Calibration = dict[str, MotorCalibration]


def parse_calibration(data: object, *, source: str = "calibration") -> Calibration:
    """Validate a decoded calibration JSON object."""
    if not isinstance(data, Mapping) or not data:
        raise CalibrationError(f"{source}: expected a JSON object of motor name -> calibration")
    result: Calibration = {}
    for name, entry in data.items():
        try:
            parsed = _Entry.model_validate(entry)
        except ValidationError as exc:
            raise CalibrationError(f"{source}: motor {name!r}: {exc}") from exc
        result[str(name)] = MotorCalibration(**parsed.model_dump())
    return result


def load_calibration(path: str | Path) -> Calibration:
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise CalibrationError(f"cannot read calibration file {path}: {exc.strerror}") from exc
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise CalibrationError(f"{path} is not JSON: {exc}") from exc
    return parse_calibration(data, source=str(path))


def dump_calibration(calibration: Mapping[str, MotorCalibration]) -> str:
    """The JSON text LeRobot itself writes (indent 4), so LeRobot loads it back unchanged."""
    return json.dumps({name: asdict(entry) for name, entry in calibration.items()}, indent=4)


def write_calibration(path: str | Path, calibration: Mapping[str, MotorCalibration]) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(dump_calibration(calibration) + "\n")
    return path


def builtin_calibration(name: str) -> Calibration:
    """A calibration shipped with the package (``so101``, ``so101_left``, ``so101_right``)."""
    resource = resources.files(f"{__package__}.data").joinpath(f"{name}.json")
    if not resource.is_file():
        raise CalibrationError(f"no built-in calibration named {name!r}")
    return parse_calibration(json.loads(resource.read_text()), source=f"built-in {name}")

"""Simulated cells: the named presets ``so101`` and ``bimanual_so101``.

A cell is one or more arms, each with its own pty (one serial bus per arm, as
on the real hardware). Presets pick the motors and the shipped calibration;
callers may override the calibration per arm (the cell's own file), latency and
where the stable port symlinks go.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from .arm import SO101_MOTORS, MotorSpec, SimulatedArm
from .calibration import Calibration, builtin_calibration
from .lifecycle import StartStop


@dataclass(frozen=True)
class ArmPreset:
    name: str
    motors: tuple[MotorSpec, ...]
    calibration: str  # built-in calibration name


PRESETS: dict[str, tuple[ArmPreset, ...]] = {
    "so101": (ArmPreset("arm", SO101_MOTORS, "so101"),),
    "bimanual_so101": (
        ArmPreset("left", SO101_MOTORS, "so101_left"),
        ArmPreset("right", SO101_MOTORS, "so101_right"),
    ),
}


class CellSimulator(Protocol):
    """What the agent and the launchers use of a running simulated cell.

    ``SimulatedCell`` (its pty threads in this process) and ``SimulatedCellProcess``
    (the same cell in a child process) both offer it; ``arms`` maps arm name to an
    object with the arm's read-back and fault methods.
    """

    preset: str
    arms: dict[str, Any]

    def ports(self) -> dict[str, str]: ...

    def joint_angles(self) -> dict[str, dict[str, float]]: ...

    def stop(self) -> None: ...


class SimulatedCell(StartStop):
    """The arms of one simulated robot cell, started and stopped together."""

    def __init__(self, arms: Mapping[str, SimulatedArm], preset: str = "custom") -> None:
        self.arms = dict(arms)
        self.preset = preset

    @property
    def arm(self) -> SimulatedArm:
        """The only arm of a single-arm cell."""
        if len(self.arms) != 1:
            raise ValueError(
                f"cell {self.preset!r} has arms {list(self.arms)}; pick one from .arms"
            )
        return next(iter(self.arms.values()))

    def joint_angles(self) -> dict[str, dict[str, float]]:
        """Degrees per motor per arm: the joint-state source a ``SimulatedCamera`` draws."""
        return {name: arm.joint_angles() for name, arm in self.arms.items()}

    def ports(self) -> dict[str, str]:
        return {name: arm.port for name, arm in self.arms.items()}

    def start(self) -> SimulatedCell:
        started: list[SimulatedArm] = []
        try:
            for arm in self.arms.values():
                arm.start()
                started.append(arm)
        except BaseException:
            for arm in started:
                arm.stop()
            raise
        return self

    def stop(self) -> None:
        for arm in self.arms.values():
            arm.stop()


def build_cell(
    preset: str,
    *,
    calibrations: Mapping[str, Calibration] | None = None,
    latency_ms: float = 0.0,
    link_dir: str | Path | None = None,
    state_dir: str | Path | None = None,
) -> SimulatedCell:
    """A not-yet-started cell for ``preset``; ``calibrations`` maps arm name -> calibration.

    The cell's pty threads run in this process; ``SimulatedCellProcess`` runs the
    same cell in a child process, which keeps reply latency low when this process
    also runs the busy-polling SDK client on a loaded machine.
    """
    try:
        arm_presets = PRESETS[preset]
    except KeyError:
        raise ValueError(
            f"unknown simulator preset {preset!r}; choose one of {sorted(PRESETS)}"
        ) from None
    overrides = dict(calibrations or {})
    unknown = set(overrides) - {a.name for a in arm_presets}
    if unknown:
        raise ValueError(
            f"preset {preset!r} has no arm(s) {sorted(unknown)}; arms: {[a.name for a in arm_presets]}"
        )
    arms = {}
    for spec in arm_presets:
        arms[spec.name] = SimulatedArm(
            spec.motors,
            overrides.get(spec.name) or builtin_calibration(spec.calibration),
            name=spec.name,
            latency_ms=latency_ms,
            link_path=Path(link_dir) / f"{preset}-{spec.name}" if link_dir is not None else None,
            # A named cell keeps its servos' saved EEPROM across simulator restarts.
            state_file=Path(state_dir) / f"{preset}-{spec.name}.eeprom.json" if state_dir is not None else None,
        )
    return SimulatedCell(arms, preset)

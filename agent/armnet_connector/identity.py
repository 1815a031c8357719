"""Motor identity: which servo a motor name means, in which unit, on which protocol — the cell's.

Why: limits, ranges and rest are the cell's, keyed by servo id. If a job could
name servo 1 ``wrist_roll``, declare a degrees joint as ``RANGE_0_100`` or pick
another protocol (whose byte order is process-global in scservo_sdk), the
cell's limits would be applied to the wrong servo, in the wrong unit, or to
byte-swapped positions. So the connector builds every bus from the cell's motor
table, and a job's ``motors`` must be a subset of it, motor for motor.

This module owns the cell's motor table (the embodiment's names and units, the
cell's calibration ids) and the comparison with a job's declaration. Pure: it
never imports LeRobot or touches a bus.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

DEGREES = "degrees"
RANGE_0_100 = "range_0_100"
RANGE_M100_100 = "range_m100_100"
NORM_MODES = frozenset({DEGREES, RANGE_0_100, RANGE_M100_100})

#: The protocol of each motor model (LeRobot's ``MODEL_PROTOCOL``): fixed by the hardware.
MODEL_PROTOCOL: Mapping[str, int] = {"sts3215": 0, "sts3250": 0, "sts_series": 0, "sms_series": 0}

#: The SO-101's motors and their units: the body in degrees, the gripper in 0..100
#: (LeRobot's ``SO101FollowerConfig(use_degrees=True)``, the simulator's and the
#: examples' convention). A cell may override a motor's unit in its arm's ``motors``.
SO101_NORM_MODES: Mapping[str, str] = {
    "shoulder_pan": DEGREES,
    "shoulder_lift": DEGREES,
    "elbow_flex": DEGREES,
    "wrist_flex": DEGREES,
    "wrist_roll": DEGREES,
    "gripper": RANGE_0_100,
}


#: Units a job may declare besides the cell's own, per cell unit: LeRobot's SO follower
#: declares its body joints in degrees (``use_degrees=True``) or in -100..100 (its
#: default). The connector converts the cell's limit to the job's unit through raw
#: ticks, so either is safe; a unit with no such conversion (0..100 on a body joint)
#: is refused.
ALSO_ACCEPTED: Mapping[str, frozenset[str]] = {DEGREES: frozenset({RANGE_M100_100})}


@dataclass(frozen=True)
class CellMotor:
    """One motor as the cell knows it; ``norm_mode`` is the unit of the cell's limit."""

    id: int
    model: str
    norm_mode: str

    def accepts(self, norm_mode: object) -> bool:
        return norm_mode == self.norm_mode or norm_mode in ALSO_ACCEPTED.get(self.norm_mode, frozenset())

    def describe(self) -> str:
        modes = sorted({self.norm_mode, *ALSO_ACCEPTED.get(self.norm_mode, frozenset())})
        return f"id {self.id}, model {self.model!r}, norm mode {' or '.join(repr(m) for m in modes)}"


@dataclass(frozen=True)
class JobMotor:
    """One motor as a job declared it (``Motor(id, model, norm_mode)``)."""

    id: object
    model: object
    norm_mode: object


def cell_motor_table(
    ids: Mapping[str, int], model: str, norm_modes: Mapping[str, str] | None = None
) -> dict[str, CellMotor]:
    """The cell's motors: ids from its calibration, units from the cell (else the SO-101 table)."""
    modes = {**SO101_NORM_MODES, **(norm_modes or {})}
    return {name: CellMotor(servo_id, model, modes.get(name, DEGREES)) for name, servo_id in ids.items()}


def motors_refusal(job: Mapping[str, JobMotor], cell: Mapping[str, CellMotor]) -> str | None:
    """Why a job's ``motors`` do not match the cell's, or ``None`` when they are a faithful subset."""
    # An empty table is allowed: such a bus can only ping (``scan_port``, ``broadcast_ping``),
    # and any write it could address still passes the register policy by servo id.
    for name, motor in job.items():
        own = cell.get(name)
        if own is None:
            return f"motor {name!r} is not a motor of this cell; the cell's motors are {describe_table(cell)}"
        if (motor.id, motor.model) != (own.id, own.model) or not own.accepts(motor.norm_mode):
            return (
                f"motor {name!r} is declared as id {motor.id!r}, model {motor.model!r}, norm mode "
                f"{motor.norm_mode!r}, but the cell has {own.describe()}; declare it as the cell does"
            )
    return None


def protocol_refusal(protocol_version: object, models: set[str]) -> str | None:
    """Why ``protocol_version`` is refused for motors of ``models`` (it is fixed by the model)."""
    wanted = {MODEL_PROTOCOL.get(model) for model in models}
    if len(wanted) == 1 and protocol_version in wanted and not isinstance(protocol_version, bool):
        return None
    return (
        f"protocol_version={protocol_version!r} is not the protocol of this cell's motors "
        f"({sorted(models)} speak protocol {sorted(str(w) for w in wanted)}); leave it at its default"
    )


def describe_table(cell: Mapping[str, CellMotor]) -> str:
    return "; ".join(f"{name}: {motor.describe()}" for name, motor in cell.items())

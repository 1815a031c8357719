"""The register write policy: which servo registers a job may write, and with which values.

Why a policy per register and not only a Goal_Position check: a servo has many
ways to move or break outside any position check. ``Operating_Mode=1`` turns a
joint into a wheel under ``Goal_Velocity``; ``Torque_Limit=0`` drops the arm;
``Lock=0`` followed by limit or homing writes rewrites the cell's calibration
in EEPROM for every later tenant. So every register write is decided here, by
register name, before it reaches the bus.

The rules follow where a register lives in the STS3215's control table (LeRobot's
``tables.py``: addresses 0-39 are EEPROM, 40-71 RAM, 80-86 factory settings kept
like EEPROM). EEPROM belongs to the cell: a job may only write the value a servo
already holds (so LeRobot's ``configure()`` on a prepared cell is a no-op). The RAM
registers a job may tune within bounds are put back by the connector when the job's
bus lets go (``restore``), so the next tenant finds the cell as this one did.

This module owns the rules as plain data (STS3215 first) and the decision
function. It never touches a bus: the caller passes the value the servo holds
where a rule needs it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from enum import StrEnum


class Rule(StrEnum):
    """How a register's writes are decided."""

    #: Goal_Position: allowed here; the motion guard checks it against the cell's limits.
    GOAL = "goal"
    #: Only the listed values (Torque_Enable 0/1).
    VALUES = "values"
    #: RAM a job may tune: only values inside the cell's bounds, and restored when its bus lets go.
    BOUNDED = "bounded"
    #: EEPROM (the cell's configuration): only the value the servo already holds, so the
    #: write changes nothing (LeRobot's ``configure()`` on a prepared cell).
    EEPROM = "eeprom"
    #: Never written by a job.
    REFUSED = "refused"


@dataclass(frozen=True)
class RegisterRule:
    rule: Rule
    #: Allowed values (VALUES).
    values: frozenset[int] = frozenset()
    #: What the register does, for the refusal message.
    why: str = ""


#: Default bounds of the BOUNDED registers (raw register units), inclusive. A cell
#: overrides them with ``registerBounds``. They hold every value LeRobot's SO-101
#: ``configure()`` writes to these RAM registers (acceleration 254) and the STS3215's
#: power-on values. Every one of them is restored when the job's bus lets go.
DEFAULT_BOUNDS: Mapping[str, tuple[int, int]] = {
    "Acceleration": (0, 254),
    "Goal_Velocity": (0, 1000),
    "Goal_Time": (0, 0),
    "Torque_Limit": (200, 1000),
}

#: The order the connector writes restored registers back in: the servo's force
#: ceiling first, then how it moves. The arm is held where it is before any of them
#: (``restore.restore_registers``), so none of them can move it.
RESTORE_ORDER: tuple[str, ...] = ("Torque_Limit", "Acceleration", "Goal_Velocity", "Goal_Time")

_EEPROM = (
    "is in the servo's EEPROM, the cell's configuration (it outlives the job and every later job "
    "depends on it)"
)
_CALIBRATION = (
    "holds the cell's calibration, owned by the cell; the calibration is provided read-only "
    "at ctx.cell.calibration_dir"
)

#: EEPROM and factory registers of the STS3215 that LeRobot's ``configure()`` (or a
#: robot's) writes: accepted when the servo already holds the value. Addresses from
#: LeRobot's control table; all below 40 (EEPROM) or in 80-86 (factory).
_STS3215_EEPROM_NOOP = (
    "Return_Delay_Time",  # 7
    "Max_Torque_Limit",  # 16: loaded into Torque_Limit at power-on
    "P_Coefficient", "D_Coefficient", "I_Coefficient",  # 21-23
    "Protection_Current",  # 28
    "Operating_Mode",  # 33: position (0), wheel (1), PWM (2), step (3)
    "Overload_Torque",  # 36
    "Maximum_Acceleration",  # 85 (factory)
)

#: STS3215 (LeRobot's ``sts3215`` control table). A register not listed is refused.
STS3215: Mapping[str, RegisterRule] = {
    "Goal_Position": RegisterRule(Rule.GOAL),
    "Torque_Enable": RegisterRule(Rule.VALUES, frozenset({0, 1}), "switches the servo's torque (0 off, 1 on)"),
    **{name: RegisterRule(Rule.BOUNDED, why="is limited to the cell's bounds") for name in DEFAULT_BOUNDS},
    **{name: RegisterRule(Rule.EEPROM, why=_EEPROM) for name in _STS3215_EEPROM_NOOP},
    "Homing_Offset": RegisterRule(Rule.REFUSED, why=_CALIBRATION),
    "Min_Position_Limit": RegisterRule(Rule.REFUSED, why=_CALIBRATION),
    "Max_Position_Limit": RegisterRule(Rule.REFUSED, why=_CALIBRATION),
    "ID": RegisterRule(Rule.REFUSED, why="re-addresses the cell's servo"),
    "Baud_Rate": RegisterRule(Rule.REFUSED, why="changes the line speed the cell's bus talks at"),
    "Lock": RegisterRule(
        Rule.REFUSED,
        why="guards the servo's EEPROM (0 makes EEPROM writes persist); the cell keeps it locked",
    ),
}

POLICIES: Mapping[str, Mapping[str, RegisterRule]] = {"sts3215": STS3215}

TORQUE_ENABLE = "Torque_Enable"


def bounds_for(register: str, overrides: Mapping[str, tuple[int, int]] | None) -> tuple[int, int] | None:
    """The inclusive bounds of a BOUNDED register: the cell's, else the default."""
    if overrides and register in overrides:
        return overrides[register]
    return DEFAULT_BOUNDS.get(register)


def is_goal_register(model: str, register: str | None) -> bool:
    """True for the register whose writes this policy leaves to the motion guard (``Rule.GOAL``).

    While the interlock is clear such a write is allowed here whatever its value, so
    the policed bus decides a whole ``sync_write`` of it with one lookup per address.
    """
    rule = POLICIES.get(model, {}).get(register) if register is not None else None
    return rule is not None and rule.rule is Rule.GOAL


def needs_current_value(model: str, register: str) -> bool:
    """True when deciding a write needs the value the servo holds (an EEPROM write must be a no-op)."""
    rule = POLICIES.get(model, {}).get(register)
    return rule is not None and rule.rule is Rule.EEPROM


def is_restored(model: str, register: str | None) -> bool:
    """True for a register whose job writes the connector puts back when the job's bus lets go."""
    rule = POLICIES.get(model, {}).get(register) if register is not None else None
    return rule is not None and rule.rule is Rule.BOUNDED


def write_refusal(
    model: str,
    register: str,
    motor: str,
    value: int,
    *,
    interlock_held: bool,
    bounds: Mapping[str, tuple[int, int]] | None = None,
    current: int | None = None,
) -> str | None:
    """Why writing raw ``value`` to ``register`` of ``motor`` is refused, or ``None`` when allowed.

    While the interlock holds, the only write allowed is torque off: letting go of
    the arm is always safe, everything else waits for the next job.
    """
    policy = POLICIES.get(model)
    if policy is None:
        return f"motor {motor!r} is a {model!r}, which has no register policy on this connector; it is not written"
    rule = policy.get(register)
    if interlock_held:
        if register == TORQUE_ENABLE and value == 0:
            return None
        return (
            f"writing {register!r} on motor {motor!r} is refused: the cell's interlock holds, and only "
            "torque off (Torque_Enable=0) is accepted until the job ends"
        )
    if rule is None or rule.rule is Rule.REFUSED:
        why = rule.why if rule is not None else "is not on this cell's register policy"
        return f"writing {register!r} on motor {motor!r} is not allowed: {register} {why}"
    if rule.rule is Rule.GOAL:
        return None
    if rule.rule is Rule.VALUES:
        if value in rule.values:
            return None
        return (
            f"writing {register}={value} on motor {motor!r} is not allowed: {register} {rule.why}; "
            f"allowed values: {sorted(rule.values)}"
        )
    if rule.rule is Rule.BOUNDED:
        low, high = bounds_for(register, bounds) or (0, -1)
        if low <= value <= high:
            return None
        return (
            f"writing {register}={value} on motor {motor!r} is not allowed: {register} {rule.why} "
            f"[{low}, {high}]"
        )
    # EEPROM
    if current is not None and current == value:
        return None
    if current is None:
        return (
            f"writing {register}={value} on motor {motor!r} is not allowed: {register} {rule.why}; a job may "
            "write it only with write(), one servo at a time, and only the value the servo already holds"
        )
    return (
        f"writing {register}={value} on motor {motor!r} is not allowed: {register} {rule.why}. The servo "
        f"holds {current}, and a job may write only that value (so LeRobot's configure() works on a cell "
        "prepared with its values); changing it is the cell owner's decision"
    )


def valid_bounds(bounds: Mapping[str, tuple[int, int]]) -> list[str]:
    """Problems with a cell's ``registerBounds`` (unknown registers, reversed ranges)."""
    problems = []
    for register, (low, high) in bounds.items():
        if STS3215.get(register, RegisterRule(Rule.REFUSED)).rule is Rule.EEPROM:
            problems.append(
                f"{register!r} is in the servos' EEPROM: jobs may only write the value the servo holds, so it "
                f"takes no bounds (set it on the servos themselves); bounded: {sorted(DEFAULT_BOUNDS)}"
            )
        elif register not in DEFAULT_BOUNDS:
            problems.append(f"{register!r} is not a bounded register; bounded: {sorted(DEFAULT_BOUNDS)}")
        elif low > high:
            problems.append(f"{register!r}: lower bound {low} is above upper bound {high}")
    return problems

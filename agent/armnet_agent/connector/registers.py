"""The register write policy: which servo registers a job may write, and with which values.

Why a policy per register and not only a Goal_Position check: a servo has many
ways to move or break outside any position check. ``Operating_Mode=1`` turns a
joint into a wheel under ``Goal_Velocity``; ``Torque_Limit=0`` drops the arm;
``Lock=0`` followed by limit or homing writes rewrites the cell's calibration
in EEPROM for every later tenant. So every register write is decided here, by
register name, before it reaches the bus.

This module owns the rules as plain data (STS3215 first) and the decision
function. It never touches a bus: the caller passes the value the servo holds
where a rule needs it (EEPROM writes are allowed only when they change nothing).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from enum import StrEnum


class Rule(StrEnum):
    """How a register's writes are decided."""

    #: Goal_Position: allowed here; the motion guard checks it against the cell's limits.
    GOAL = "goal"
    #: Only the listed values (e.g. Torque_Enable 0/1, Operating_Mode position only).
    VALUES = "values"
    #: Only values inside the cell's bounds for that register (PID, acceleration, torque).
    BOUNDED = "bounded"
    #: EEPROM a job never changes: only the exact value LeRobot's ``configure()`` writes,
    #: and only when the servo already holds it (so the write is a no-op).
    CONFIGURE_NOOP = "configure_noop"
    #: Never written by a job.
    REFUSED = "refused"


@dataclass(frozen=True)
class RegisterRule:
    rule: Rule
    #: Allowed values (VALUES) or LeRobot's configure value (CONFIGURE_NOOP).
    values: frozenset[int] = frozenset()
    #: What the register does, for the refusal message.
    why: str = ""


#: Default bounds of the BOUNDED registers (raw register units), inclusive. A cell
#: overrides them with ``registerBounds``. They hold every value LeRobot's SO-101
#: ``configure()`` writes (P=16, I=0, D=32, acceleration 254, gripper torque 500,
#: protection current 250, overload torque 25) and the STS3215 factory values.
DEFAULT_BOUNDS: Mapping[str, tuple[int, int]] = {
    "P_Coefficient": (8, 32),
    "I_Coefficient": (0, 8),
    "D_Coefficient": (0, 32),
    "Acceleration": (0, 254),
    "Maximum_Acceleration": (0, 254),
    "Goal_Velocity": (0, 1000),
    "Goal_Time": (0, 0),
    "Torque_Limit": (200, 1000),
    "Max_Torque_Limit": (200, 1000),
    "Protection_Current": (100, 500),
    "Overload_Torque": (10, 100),
}

_EEPROM = (
    "is the servo's EEPROM configuration, owned by the cell (it survives power cycles and "
    "every later job depends on it)"
)
_CALIBRATION = (
    "holds the cell's calibration, owned by the cell; the calibration is provided read-only "
    "at ctx.cell.calibration_dir"
)

#: STS3215 (LeRobot's ``sts3215`` control table). A register not listed is refused.
STS3215: Mapping[str, RegisterRule] = {
    "Goal_Position": RegisterRule(Rule.GOAL),
    "Torque_Enable": RegisterRule(Rule.VALUES, frozenset({0, 1}), "switches the servo's torque (0 off, 1 on)"),
    "Operating_Mode": RegisterRule(
        Rule.VALUES, frozenset({0}),
        "selects position (0), wheel/velocity (1), PWM (2) or step (3) mode; only position mode "
        "keeps the cell's position limits meaningful",
    ),
    **{name: RegisterRule(Rule.BOUNDED, why="is limited to the cell's bounds") for name in DEFAULT_BOUNDS},
    "Return_Delay_Time": RegisterRule(Rule.CONFIGURE_NOOP, frozenset({0}), _EEPROM),
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
    """True when deciding a write needs the value the servo holds (a no-op EEPROM write)."""
    rule = POLICIES.get(model, {}).get(register)
    return rule is not None and rule.rule is Rule.CONFIGURE_NOOP


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
    # CONFIGURE_NOOP
    if value in rule.values and current == value:
        return None
    held = "unknown" if current is None else str(current)
    return (
        f"writing {register}={value} on motor {motor!r} is not allowed: {register} {rule.why}. "
        f"The servo holds {held}; only LeRobot's configure() value {sorted(rule.values)} is accepted, "
        "and only when the servo already holds it"
    )


def valid_bounds(bounds: Mapping[str, tuple[int, int]]) -> list[str]:
    """Problems with a cell's ``registerBounds`` (unknown registers, reversed ranges)."""
    problems = []
    for register, (low, high) in bounds.items():
        if register not in DEFAULT_BOUNDS:
            problems.append(f"{register!r} is not a bounded register; bounded: {sorted(DEFAULT_BOUNDS)}")
        elif low > high:
            problems.append(f"{register!r}: lower bound {low} is above upper bound {high}")
    return problems

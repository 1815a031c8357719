"""The motion guard: applies the interlock and the safety rules to one bus call.

This module owns the I/O side of safety: pulling the goal values out of a
``write``/``sync_write`` call exactly as the real method would bind them,
reading the present position (or reusing a fresh one), and tripping the
interlock on a violation. The rules themselves live in ``safety``.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
import operator
import time
from collections.abc import Mapping
from typing import Any

from .allowlist import CALIBRATION_METHODS, CLASSES
from .config import MotorRange
from .errors import RequestError
from .hardware import Handle
from .interlock import Interlock, TripReason
from .report import SafetyRecorder
from .retry import with_read_retry
from .safety import (
    GOAL_POSITION,
    PROTECTED_REGISTERS,
    GoalScreen,
    MotorFacts,
    MotorLimit,
    compile_limits,
    decide_goals,
    is_release_write,
)

CALIBRATION_REFUSAL = (
    "{method} is not allowed: the cell's calibration belongs to the cell, and a job never rewrites it "
    "(homing offsets and position limits live in the servos' EEPROM, and every later job depends on "
    "them). Use the cell's calibration, provided read-only at ctx.cell.calibration_dir; a cell whose "
    "owner allows calibration jobs (allowCalibrationJobs) runs them."
)

_signatures: dict[tuple[type, str], inspect.Signature] = {}
#: Per (class, method): (positional parameter names after ``self``, all parameter names,
#: required names), or ``None`` when the signature has ``*args``, ``**kwargs`` or
#: positional-only parameters.
_Shape = tuple[tuple[str, ...], frozenset[str], frozenset[str]]
_simple_shapes: dict[tuple[type, str], _Shape | None] = {}


def _signature(obj: Any, method: str) -> inspect.Signature:
    key = (type(obj), method)
    sig = _signatures.get(key)
    if sig is None:
        sig = _signatures[key] = inspect.signature(getattr(type(obj), method))
    return sig


def _simple_shape(obj: Any, method: str) -> _Shape | None:
    key = (type(obj), method)
    if key not in _simple_shapes:
        params = list(_signature(obj, method).parameters.values())[1:]  # drop self
        simple = all(p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY) for p in params)
        _simple_shapes[key] = (
            tuple(p.name for p in params if p.kind is p.POSITIONAL_OR_KEYWORD),
            frozenset(p.name for p in params),
            frozenset(p.name for p in params if p.default is p.empty),
        ) if simple else None
    return _simple_shapes[key]


#: Per (class, method, number of positional arguments, keyword names in call order) of a call
#: that binds plainly: the parameter names the positional arguments bind to. Only shapes that
#: bind are kept: their keywords are parameter names, so they are few for any signature. A shape
#: ``Signature.bind`` decides (not plain, or refused) is never kept: its key would hold names and
#: counts a job chose (up to a request line each), and refusals would fill the table.
_bindings: dict[tuple[type, str, int, tuple[str, ...]], tuple[str, ...]] = {}
_MAX_BINDINGS = 1024


def _binding(obj: Any, method: str, positional_count: int, keywords: tuple[str, ...]) -> tuple[str, ...] | None:
    """The names ``positional_count`` positional arguments bind to, when a call of this shape binds plainly."""
    shape = _simple_shape(obj, method)
    if shape is None:
        return None
    positional, names, required = shape
    if positional_count > len(positional):
        return None
    bound = positional[:positional_count]
    if any(k not in names or k in bound for k in keywords):
        return None
    return bound if required <= {*bound, *keywords} else None


def _bound_arguments(obj: Any, method: str, args: list[Any], kwargs: dict[str, Any]) -> dict[str, Any]:
    """The arguments a call passes, by parameter name (defaults not applied), as ``Signature.bind`` would.

    Why not always ``bind``: it costs tens of microseconds per call on a 100 Hz
    control path. Whether a call binds, and to which names, depends only on its
    shape (the method, how many positional arguments, which keywords), so a shape
    that binds is worked out once and kept; the values are bound on every call.
    A shape that is not plain (``*args``, positional-only) or that ``bind`` would
    refuse goes through ``bind`` for its exact error.
    """
    key = (type(obj), method, len(args), tuple(kwargs))
    names = _bindings.get(key)
    if names is None:
        names = _binding(obj, method, len(args), key[3])
        if names is not None and len(_bindings) < _MAX_BINDINGS:
            _bindings[key] = names
    if names is not None:
        bound = dict(zip(names, args, strict=True))
        if kwargs:
            bound.update(kwargs)
        return bound
    try:
        return dict(_signature(obj, method).bind(obj, *args, **kwargs).arguments)
    except TypeError as exc:
        raise RequestError("TypeError", f"{method}(...): {exc}") from None


class BadMotorValue(RequestError):
    """A motor value that is not a finite number: a ``ValueError`` on the wire, as LeRobot raises.

    ``kind`` ("wrong_type" or "non_finite") is what the safety report records;
    the job only sees the LeRobot exception type.
    """

    def __init__(self, kind: str, message: str) -> None:
        super().__init__("ValueError", message)
        self.kind = kind


def _number(motor: str, value: Any) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise BadMotorValue(
            "wrong_type", f"the value for motor {motor!r} must be a number, got {type(value).__name__}"
        ) from None
    if not math.isfinite(number):
        raise BadMotorValue("non_finite", f"the value for motor {motor!r} is not a finite number: {value!r}")
    return number


def write_arguments(handle: Handle, method: str, args: list[Any], kwargs: dict[str, Any]) -> tuple[str, dict[str, float], bool]:
    """(register, {motor: value}, normalize) of a ``write``/``sync_write`` call, bound like the real one."""
    arguments = _bound_arguments(handle.obj, method, args, kwargs)
    return _write_values(handle, method, arguments)


def _write_values(handle: Handle, method: str, arguments: dict[str, Any]) -> tuple[str, dict[str, float], bool]:
    data_name = arguments.get("data_name")
    normalize = bool(arguments.get("normalize", True))
    if method == "write":
        motor = arguments.get("motor")
        if type(motor) is not str:
            raise RequestError("TypeError", f"{method}: motor must be a motor name (str), got {type(motor).__name__}")
        values = {motor: _number(motor, arguments.get("value"))}
    else:
        raw = arguments.get("values")
        # Every key a str and every value a finite float: the goals are taken as they are.
        # Why: a control loop's goals always are, and checking them in C loops costs less than
        # converting them one by one. The sum of finite floats is finite unless it overflows to
        # inf (then the goals take the per-motor path, which decides exactly); any nan or inf
        # among them makes it non-finite.
        if (
            type(raw) is dict and set(map(type, raw.values())) <= _FLOAT_ONLY and set(map(type, raw)) <= _STR_ONLY
            and math.isfinite(sum(raw.values()))
        ):
            values = dict(raw)
        elif isinstance(raw, dict):
            values = {}
            for name, v in raw.items():
                if type(name) is not str:
                    # Refused, not converted: str() of a look-alike (a str enum member equal to a
                    # motor's name) would check one motor while LeRobot writes another.
                    raise RequestError(
                        "TypeError", f"{method}: values must be keyed by motor names (str), got {type(name).__name__}"
                    )
                # A finite float is taken as it is (the control loop's goals); anything else is converted or refused.
                values[name] = v if type(v) is float and math.isfinite(v) else _number(name, v)
        else:
            values = {m: _number(m, raw) for m in handle.obj.motors}
    return str(data_name), values, normalize


_FLOAT_ONLY = frozenset({float})
_STR_ONLY = frozenset({str})
#: How ``sync_write(data_name, values)`` binds two positional arguments (``_bindings``).
_DATA_NAME_VALUES = ("data_name", "values")


def calibration_problem(calibration: Any) -> str | None:
    """Why ``calibration`` is not a calibration LeRobot can write (None when it is one).

    LeRobot's ``write_calibration`` keeps the job's dict as the bus's calibration without
    looking at its values, and the guard converts every later goal with it: a value that
    is not a whole number (an array, a float, a bool) must not get that far.
    """
    if type(calibration) is not dict or not calibration:
        return "calibration_dict must be a non-empty dict of motor name -> MotorCalibration"
    for motor, entry in calibration.items():
        if type(motor) is not str:
            return f"motor names must be str, got {type(motor).__name__}"
        if not dataclasses.is_dataclass(entry) or isinstance(entry, type):
            return f"{motor}: expected a MotorCalibration, got {type(entry).__name__}"
        for field in dataclasses.fields(entry):
            value = getattr(entry, field.name)
            if type(value) is not int:
                return f"{motor}.{field.name} must be an int, got {type(value).__name__}"
        drive_mode = getattr(entry, "drive_mode", 0)
        if drive_mode not in (0, 1):
            return f"{motor}.drive_mode must be 0 or 1, got {drive_mode}"
    return None


def _motor_range(calibration: Any, motor: str) -> MotorRange | None:
    cal = (calibration or {}).get(motor)
    if cal is None:
        return None
    return MotorRange(cal.id, cal.range_min, cal.range_max, cal.drive_mode)


#: The values of a ``MotorCalibration`` the facts are built from, read in one C call.
_calibration_values = operator.attrgetter("id", "range_min", "range_max", "drive_mode")


#: A ``Motor``'s norm mode, read in a C call.
_norm_mode = operator.attrgetter("norm_mode")


def _facts_key(handle: Handle, names: tuple[str, ...]) -> tuple[Any, ...]:
    """The values the facts of ``names`` are built from: their norm modes and calibrations, read in C loops.

    The key holds values (not object identities), so an in-place edit of a calibration
    is seen too; ``map`` reads them with one Python step per write, not per motor.
    """
    calibration = handle.obj.calibration or {}
    calibrations = tuple(map(calibration.get, names))
    try:
        calibrated: tuple[Any, ...] = tuple(map(_calibration_values, calibrations))
    except AttributeError:  # a motor without calibration (None)
        calibrated = tuple(None if cal is None else _calibration_values(cal) for cal in calibrations)
    return (names, tuple(map(_norm_mode, map(handle.obj.motors.__getitem__, names))), calibrated)


def _motor_facts(handle: Handle, motors: Any) -> dict[str, MotorFacts]:
    """The facts of ``motors``, rebuilt only when a motor's mode or calibration changed (``_facts_key``).

    Why a cache: building them costs more than the rest of the check at 100 Hz, and
    they change only when the customer recalibrates.
    """
    names = tuple(motors)
    epoch = handle.calibration_epoch
    key = _facts_key(handle, names)
    cached = handle.facts_cache
    if cached is not None and cached[0] == key:
        handle.facts_epoch = epoch  # compared by value: current until the next call that may recalibrate
        return cached[1]
    bus_motors = handle.obj.motors
    calibration = handle.obj.calibration or {}
    facts = {
        m: MotorFacts(
            getattr(bus_motors[m].norm_mode, "value", str(bus_motors[m].norm_mode)),
            _motor_range(calibration, m),
            handle.cell_ranges.get(m),
            handle.cell_motors[m].norm_mode if m in handle.cell_motors else None,
        )
        for m in names
    }
    handle.facts_cache = (key, facts)
    # Only now: a comparison or a build that raised (a calibration of odd values) leaves the
    # old facts untrusted by the fast path, so every later write takes the long way again.
    handle.facts_epoch = epoch
    return facts


def _goal_rules(
    handle: Handle, motors: Any, limit: Any, normalize: bool
) -> tuple[Mapping[str, MotorLimit], GoalScreen | None]:
    """The compiled goal rules of ``motors`` (``safety.compile_limits``) and their ``GoalScreen``.

    Both are rebuilt only when the motors' facts are (a recalibration, another motor
    list) or the limit changes; the check of each goal against them runs on every write.
    """
    facts = _motor_facts(handle, motors)
    cached = handle.limits_cache
    if cached is None or cached[0] is not facts or cached[1] is not limit:
        cached = handle.limits_cache = (facts, limit, {})
    rules = cached[2].get(normalize)
    if rules is None:
        limits = compile_limits(facts, limit, normalize=normalize)
        rules = cached[2][normalize] = (limits, GoalScreen.build(tuple(facts), limits))
    return rules


def _replace_argument(obj: Any, method: str, args: list[Any], kwargs: dict[str, Any], name: str, value: Any) -> None:
    """Put ``value`` where the call passed parameter ``name`` (the clamp rewrites the call in place)."""
    if name in kwargs:
        kwargs[name] = value
        return
    positional = [p.name for p in list(_signature(obj, method).parameters.values())[1:]]
    args[positional.index(name)] = value


#: Per (class, method) of the allow-list: (rewrites the calibration, moves the arm, writes goals).
#: Any other method is none of these (``check`` lets it through).
_METHOD_KINDS: dict[tuple[str, str], tuple[bool, bool, bool]] = {
    (class_name, method): (
        method in CALIBRATION_METHODS.get(class_name, ()), method in rules.motion, method in rules.goal_writers,
    )
    for class_name, rules in CLASSES.items()
    for method in rules.methods | rules.motion | rules.goal_writers | CALIBRATION_METHODS.get(class_name, frozenset())
}
_NO_MOTION = (False, False, False)

#: The calls that never change a bus's calibration or its motors' norm modes: LeRobot's
#: reads and writes of registers use them, never assign or edit them (a test holds the
#: installed LeRobot to it). Any other call on a handle moves ``Handle.calibration_epoch``,
#: and the goal fast path trusts the motors' facts only while that stays where it was
#: when they were last compared by value (``_motor_facts``). Nothing else can change
#: them: the calibration is not assignable through the connector, and a job reaches the
#: real object only through calls.
KEEPS_CALIBRATION = frozenset({"sync_read", "sync_write", "read", "write"})


class MotionGuard:
    """Decides, per call, whether a motion request reaches the bus (see ``safety``)."""

    def __init__(self, interlock: Interlock, present_max_age_s: float, counters: Any, *, policy: str = "clamp") -> None:
        self.interlock = interlock
        self.present_max_age_s = present_max_age_s
        self.counters = counters
        self.policy = policy
        self.recorder = SafetyRecorder(policy)

    def check(self, handle: Handle, method: str, args: list[Any], kwargs: dict[str, Any]) -> None:
        """Raise ``RequestError`` if the call must not reach the device; caller holds the device lock.

        Under ``safetyPolicy: clamp`` a goal write beyond the relative limit is not
        refused: its goals are clamped, and ``args``/``kwargs`` are rewritten in place.
        """
        if method not in KEEPS_CALIBRATION:
            handle.calibration_epoch += 1  # this call may change the bus's calibration (see KEEPS_CALIBRATION)
        calibration, motion, goal_writer = _METHOD_KINDS.get((handle.class_name, method), _NO_MOTION)
        if calibration and not handle.allow_calibration:
            message = CALIBRATION_REFUSAL.format(method=method)
            self.recorder.record_refusal("calibration", None, message, tripped=False)
            raise RequestError("NotAllowed", message)
        if method == "write_calibration":
            problem = calibration_problem(_bound_arguments(handle.obj, method, args, kwargs).get("calibration_dict"))
            if problem is not None:
                raise RequestError("TypeError", f"write_calibration: {problem}; nothing was written")
        if not motion:
            return
        if goal_writer and method == "sync_write" and not kwargs and self._accepts_plain_goals(handle, args):
            return
        refusal = self.interlock.refusal()
        if not goal_writer:
            if refusal is not None:
                raise RequestError(*refusal)
            return
        arguments = _bound_arguments(handle.obj, method, args, kwargs)
        try:
            data_name, values, normalize = _write_values(handle, method, arguments)
        except BadMotorValue as exc:
            if arguments.get("data_name") == GOAL_POSITION:
                self._refuse_goal(exc, exc.kind)
            raise
        if data_name in PROTECTED_REGISTERS:
            raise RequestError(
                "NotAllowed", f"writing {data_name!r} would re-address the cell's servos; it is not allowed"
            )
        if refusal is not None and not is_release_write(data_name, values):
            raise RequestError(*refusal)
        if data_name == GOAL_POSITION:
            clamped = self._check_goals(handle, values, normalize)
            if clamped:
                self._rewrite(handle, method, args, kwargs, arguments, clamped)

    def _accepts_plain_goals(self, handle: Handle, args: list[Any]) -> bool:
        """True when a control loop's ``sync_write("Goal_Position", {motor: float})`` passes, decided in one step.

        False: ``check`` decides the write the long way, as if this had not run
        (nothing is recorded or changed here before the answer is True).

        Why: the long way is a chain of small steps (bind, take the values, read the
        positions, find the rules, screen, record), and after a paced loop's 10 ms
        pause each costs several microseconds of cold caches. This takes the write
        only when every fact the long way would use is at hand and current: the
        interlock clear; the call's shape bound as (data_name, values) by
        ``_bound_arguments`` before; the goals finite floats, for exactly the motors
        (in the order) the facts were built for, which the long way took only from
        the bus's motors; this tick's positions fresh; the motors' facts compared by value
        (``_facts_key``) since the last call that may have changed the calibration
        (``KEEPS_CALIBRATION``); their rules and screen compiled for them and this
        limit. The same ``GoalScreen.step_sizes`` then decides, and the steps are recorded.
        """
        obj = handle.obj
        goals = args[1] if len(args) == 2 else None
        if (
            type(goals) is not dict or not goals or type(args[0]) is not str or args[0] != GOAL_POSITION
            or self.interlock.tripped
            or _bindings.get((type(obj), "sync_write", 2, ())) != _DATA_NAME_VALUES
            or not set(map(type, goals.values())) <= _FLOAT_ONLY or not math.isfinite(sum(goals.values()))
            or handle.arm_config is None
        ):
            return False
        limit = handle.arm_config.safety_limit
        present = handle.present.get(True)
        facts, compiled = handle.facts_cache, handle.limits_cache
        if (
            limit is None or present is None or time.monotonic() - present[0] > self.present_max_age_s
            or facts is None or compiled is None
            or compiled[0] is not facts[1] or compiled[1] is not limit
        ):
            return False
        rules = compiled[2].get(True)
        if (
            rules is None or rules[1] is None
            or handle.facts_epoch != handle.calibration_epoch or facts[0][0] != tuple(goals)
        ):
            return False
        screen = rules[1]
        sizes = screen.step_sizes(goals, present[1])
        if sizes is None:
            return False
        self.recorder.record_step_sizes(screen.motors, sizes)
        return True

    def _refuse_goal(self, exc: RequestError, kind: str) -> None:
        """A goal that is not a finite number: refused, and the interlock trips (as any refused goal)."""
        self.counters.safety_violations += 1
        tripped = self.interlock.trip(TripReason.SAFETY, exc.message)
        self.recorder.record_refusal(kind, None, exc.message, tripped=tripped)

    def _check_goals(self, handle: Handle, goals: dict[str, float], normalize: bool) -> dict[str, float]:
        """The goals the policy clamped (motor -> new goal); raises on a violation."""
        motors = handle.obj.motors
        known = goals if motors.keys() >= goals.keys() else {m: v for m, v in goals.items() if m in motors}
        if not known:
            return {}
        limit = handle.arm_config.safety_limit if handle.arm_config is not None else None
        present = self._present(handle, known, normalize) if limit is not None else {}
        limits, screen = _goal_rules(handle, known, limit, normalize)
        if screen is not None:
            sizes = screen.step_sizes(known, present)
            if sizes is not None:  # every goal passes on its own: what decide_goals decides, in C loops
                self.recorder.record_step_sizes(screen.motors, sizes)
                return {}
        decision = decide_goals(known, present, limits, normalize=normalize, clamp=self.policy == "clamp")
        if decision.steps:
            self.recorder.record_steps(decision.steps)
        violation = decision.violation
        if violation is None:
            for motor in decision.clamped:
                self.recorder.record_clamp(motor, arm=handle.arm, goal=decision.goals[motor],
                                           units="normalized" if normalize else "raw")
            return {m: decision.goals[m] for m in decision.clamped}
        self.counters.safety_violations += 1
        message = violation.message()
        tripped = self.interlock.trip(TripReason.SAFETY, message)
        kind = "out_of_range" if violation.kind == "absolute" else "relative"
        self.recorder.record_refusal(kind, violation.motor, message, tripped=tripped, arm=handle.arm)
        raise RequestError(
            "SafetyViolation", message, motor=violation.motor, step=violation.step,
            limit=violation.limit, requested=violation.requested,
        )

    @staticmethod
    def _rewrite(
        handle: Handle, method: str, args: list[Any], kwargs: dict[str, Any], arguments: dict[str, Any],
        clamped: dict[str, float],
    ) -> None:
        if method == "write":
            _replace_argument(handle.obj, method, args, kwargs, "value", next(iter(clamped.values())))
            return
        raw = arguments.get("values")
        values = dict(raw) if isinstance(raw, dict) else dict.fromkeys(handle.obj.motors, raw)
        values.update(clamped)
        _replace_argument(handle.obj, method, args, kwargs, "values", values)

    def _present(self, handle: Handle, motors: dict[str, float], normalize: bool) -> dict[str, float]:
        cached = handle.present.get(normalize)
        if cached is not None and time.monotonic() - cached[0] <= self.present_max_age_s:
            if cached[1].keys() >= motors.keys():
                return cached[1]
        names = list(motors)
        values = with_read_retry(
            handle, "sync_read", lambda: handle.obj.sync_read("Present_Position", names, normalize=normalize),
            on_retry=self._count_retry,
        )
        return {m: float(v) for m, v in values.items()}

    def _count_retry(self) -> None:
        self.counters.bus_retries += 1

    @staticmethod
    def remember_present(handle: Handle, args: list[Any], kwargs: dict[str, Any], result: Any) -> None:
        """Keep a customer's Present_Position ``sync_read`` so the next goal check can reuse it."""
        name = args[0] if args else kwargs.get("data_name")
        if name == "Present_Position" and isinstance(result, dict):
            normalize = bool(kwargs.get("normalize", True))
            handle.present[normalize] = (time.monotonic(), dict(zip(result, map(float, result.values()), strict=True)))

"""The motion guard: applies the interlock and the safety rules to one bus call.

This module owns the I/O side of safety: pulling the goal values out of a
``write``/``sync_write`` call exactly as the real method would bind them,
reading the present position (or reusing a fresh one), and tripping the
interlock on a violation. The rules themselves live in ``safety``.
"""

from __future__ import annotations

import inspect
import math
import time
from typing import Any

from .allowlist import CLASSES
from .config import MotorRange
from .errors import RequestError
from .hardware import Handle
from .interlock import Interlock, TripReason
from .safety import (
    GOAL_POSITION,
    PROTECTED_REGISTERS,
    MotorFacts,
    check_goal_write,
    is_release_write,
)

_signatures: dict[tuple[type, str], inspect.Signature] = {}


def _signature(obj: Any, method: str) -> inspect.Signature:
    key = (type(obj), method)
    sig = _signatures.get(key)
    if sig is None:
        sig = _signatures[key] = inspect.signature(getattr(type(obj), method))
    return sig


def _number(motor: str, value: Any) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise RequestError(
            "TypeError", f"the value for motor {motor!r} must be a number, got {type(value).__name__}"
        ) from None
    if not math.isfinite(number):
        raise RequestError("ValueError", f"the value for motor {motor!r} is not a finite number: {value!r}")
    return number


def write_arguments(handle: Handle, method: str, args: list[Any], kwargs: dict[str, Any]) -> tuple[str, dict[str, float], bool]:
    """(register, {motor: value}, normalize) of a ``write``/``sync_write`` call, bound like the real one."""
    try:
        bound = _signature(handle.obj, method).bind(handle.obj, *args, **kwargs)
    except TypeError as exc:
        raise RequestError("TypeError", f"{method}(...): {exc}") from None
    data_name = bound.arguments.get("data_name")
    normalize = bool(bound.arguments.get("normalize", True))
    if method == "write":
        motor = bound.arguments.get("motor")
        values = {str(motor): _number(str(motor), bound.arguments.get("value"))}
    else:
        raw = bound.arguments.get("values")
        if isinstance(raw, dict):
            values = {str(m): _number(str(m), v) for m, v in raw.items()}
        else:
            values = {m: _number(m, raw) for m in handle.obj.motors}
    return str(data_name), values, normalize


def _motor_range(calibration: Any, motor: str) -> MotorRange | None:
    cal = (calibration or {}).get(motor)
    if cal is None:
        return None
    return MotorRange(cal.id, cal.range_min, cal.range_max, cal.drive_mode)


class MotionGuard:
    """Decides, per call, whether a motion request reaches the bus (see ``safety``)."""

    def __init__(self, interlock: Interlock, present_max_age_s: float, counters: Any) -> None:
        self.interlock = interlock
        self.present_max_age_s = present_max_age_s
        self.counters = counters

    def check(self, handle: Handle, method: str, args: list[Any], kwargs: dict[str, Any]) -> None:
        """Raise ``RequestError`` if the call must not reach the device; caller holds the device lock."""
        rules = CLASSES[handle.class_name]
        if method not in rules.motion:
            return
        refusal = self.interlock.refusal()
        if method not in rules.goal_writers:
            if refusal is not None:
                raise RequestError(*refusal)
            return
        data_name, values, normalize = write_arguments(handle, method, args, kwargs)
        if data_name in PROTECTED_REGISTERS:
            raise RequestError(
                "NotAllowed", f"writing {data_name!r} would re-address the cell's servos; it is not allowed"
            )
        if refusal is not None and not is_release_write(data_name, values):
            raise RequestError(*refusal)
        if data_name == GOAL_POSITION:
            self._check_goals(handle, values, normalize)

    def _check_goals(self, handle: Handle, goals: dict[str, float], normalize: bool) -> None:
        motors = handle.obj.motors
        known = {m: v for m, v in goals.items() if m in motors}
        if not known:
            return
        limit = handle.arm_config.safety_limit if handle.arm_config is not None else None
        present = self._present(handle, list(known), normalize) if limit is not None else {}
        calibration = handle.obj.calibration
        facts = {
            m: MotorFacts(
                getattr(motors[m].norm_mode, "value", str(motors[m].norm_mode)),
                _motor_range(calibration, m),
                handle.cell_ranges.get(m),
            )
            for m in known
        }
        violation = check_goal_write(known, present, facts, limit, normalize=normalize)
        if violation is None:
            return
        self.counters.safety_violations += 1
        message = violation.message()
        self.interlock.trip(TripReason.SAFETY, message)
        raise RequestError(
            "SafetyViolation", message, motor=violation.motor, step=violation.step,
            limit=violation.limit, requested=violation.requested,
        )

    def _present(self, handle: Handle, motors: list[str], normalize: bool) -> dict[str, float]:
        cached = handle.present.get(normalize)
        if cached is not None and time.monotonic() - cached[0] <= self.present_max_age_s:
            if all(m in cached[1] for m in motors):
                return cached[1]
        values = handle.obj.sync_read("Present_Position", motors, normalize=normalize)
        return {m: float(v) for m, v in values.items()}

    @staticmethod
    def remember_present(handle: Handle, args: list[Any], kwargs: dict[str, Any], result: Any) -> None:
        """Keep a customer's Present_Position ``sync_read`` so the next goal check can reuse it."""
        name = args[0] if args else kwargs.get("data_name")
        if name == "Present_Position" and isinstance(result, dict):
            normalize = bool(kwargs.get("normalize", True))
            handle.present[normalize] = (time.monotonic(), {m: float(v) for m, v in result.items()})

"""Caps on the retry counts and timeouts a job passes to a device call.

A job chooses ``num_retry`` and ``timeout_ms`` for its own calls, but every
call runs under the device's lock: ``num_retry=10**9`` on a servo that does not
answer would hold the arm's lock (and block the connector's own torque off)
for days. This module owns the caps, as plain data, and the pure function that
applies them to a call's arguments. It never refuses a call: a value over its
cap is lowered to the cap (LeRobot's own code stays far below every cap).
"""

from __future__ import annotations

import inspect
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

#: The largest ``num_retry`` a job's bus call keeps (LeRobot itself uses at most 5).
MAX_NUM_RETRY = 5
#: The largest packet timeout a job may set on a bus (LeRobot's default is 1000 ms).
MAX_BUS_TIMEOUT_MS = 1000
#: The longest a camera read may wait for a frame.
MAX_CAMERA_TIMEOUT_MS = 5000

#: Per class: parameter name -> (cap, smallest value kept).
CAPS: Mapping[str, Mapping[str, tuple[float, float]]] = {
    "FeetechMotorsBus": {"num_retry": (MAX_NUM_RETRY, 0), "timeout_ms": (MAX_BUS_TIMEOUT_MS, 1)},
    "OpenCVCamera": {"timeout_ms": (MAX_CAMERA_TIMEOUT_MS, 0), "max_age_ms": (MAX_CAMERA_TIMEOUT_MS, 0)},
}


@dataclass(frozen=True)
class Capped:
    """A call's arguments after the caps, and which parameters were lowered."""

    args: list[Any]
    kwargs: dict[str, Any]
    lowered: tuple[str, ...] = ()


def _capped_value(value: Any, cap: float, floor: float) -> Any:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return value  # not a number: the real call refuses it with its own error
    if value != value:  # NaN
        return floor
    return type(value)(min(cap, max(floor, value)))


def capped_parameters(class_name: str, method: Any) -> tuple[str, ...]:
    """The parameter names of ``method`` (a bound method) when any of them is capped, else ``()``.

    Computed once per (object, method) by the caller: a signature costs more than
    the rest of a control-loop call.
    """
    caps = CAPS.get(class_name)
    if not caps:
        return ()
    try:
        parameters = tuple(inspect.signature(method).parameters)
    except (TypeError, ValueError):
        return ()
    return parameters if any(name in caps for name in parameters) else ()


def first_capped(class_name: str, parameters: tuple[str, ...]) -> int:
    """The position of the first capped parameter in ``parameters`` (``len(parameters)`` when none).

    A call with fewer positional arguments and no keyword arguments passes no capped
    value: ``cap_call`` has nothing to do (the control loop's usual call).
    """
    caps = CAPS.get(class_name, {})
    return next((index for index, name in enumerate(parameters) if name in caps), len(parameters))


def cap_call(class_name: str, parameters: tuple[str, ...], args: list[Any], kwargs: dict[str, Any]) -> Capped:
    """``args``/``kwargs`` of a call with every capped parameter held within its cap,
    wherever the job passed it (by position or by name). ``parameters``: the method's
    parameter names, from ``capped_parameters``."""
    caps = CAPS.get(class_name)
    if not caps or not parameters:
        return Capped(args, kwargs)
    positional = parameters[: len(args)]
    if not any(name in kwargs or name in positional for name in caps):
        return Capped(args, kwargs)  # the usual control-loop call: nothing to look at, nothing copied
    args, kwargs = list(args), dict(kwargs)
    lowered: list[str] = []
    for name, (cap, floor) in caps.items():
        if name in kwargs:
            new = _capped_value(kwargs[name], cap, floor)
            if new is not kwargs[name] and new != kwargs[name]:
                kwargs[name] = new
                lowered.append(name)
        elif name in parameters and parameters.index(name) < len(args):
            index = parameters.index(name)
            new = _capped_value(args[index], cap, floor)
            if new is not args[index] and new != args[index]:
                args[index] = new
                lowered.append(name)
    return Capped(args, kwargs, tuple(lowered))

"""The motion guard's fast paths decide exactly as the slow ones they replace.

``_bound_arguments`` must bind every call like ``inspect.Signature.bind`` on the
real LeRobot methods, and the cached motor facts must follow a recalibration,
including one that edits a calibration entry in place.
"""

from __future__ import annotations

import dataclasses
import inspect
from typing import Any

import pytest
from armnet_agent.connector.errors import RequestError
from armnet_agent.connector.hardware import DeviceLock, Handle
from armnet_agent.connector.motion import _bound_arguments, _motor_facts
from lerobot.motors.feetech import FeetechMotorsBus

pytestmark = pytest.mark.unit

CALLS: list[tuple[str, list[Any], dict[str, Any]]] = [
    ("sync_write", ["Goal_Position", {"gripper": 1.0}], {}),
    ("sync_write", ["Goal_Position"], {"values": {}}),
    ("sync_write", ["Goal_Position", {}], {"normalize": False, "num_retry": 2}),
    ("sync_write", [], {"data_name": "Goal_Position", "values": 3}),
    ("sync_write", ["Goal_Position", {}, True], {}),  # normalize is keyword-only
    ("sync_write", ["Goal_Position"], {}),  # values missing
    ("sync_write", ["Goal_Position", {}], {"data_name": "Lock"}),  # given twice
    ("sync_write", ["Goal_Position", {}], {"bogus": 1}),
    ("sync_write", ["Goal_Position", {}], {"self": 1}),
    ("write", ["Goal_Position", "gripper", 3], {}),
    ("write", ["Goal_Position", "gripper"], {"value": 3, "normalize": False}),
    ("write", ["Goal_Position", "gripper", 3, 4], {}),
]


def reference(bus: Any, method: str, args: list[Any], kwargs: dict[str, Any]) -> dict[str, Any] | str:
    try:
        bound = inspect.signature(getattr(FeetechMotorsBus, method)).bind(bus, *args, **kwargs)
    except TypeError:
        return "TypeError"
    return {name: value for name, value in bound.arguments.items() if name != "self"}


@pytest.mark.parametrize(("method", "args", "kwargs"), CALLS)
def test_calls_are_bound_like_signature_bind(
    method: str, args: list[Any], kwargs: dict[str, Any], motors: dict[str, Any]
) -> None:
    bus = FeetechMotorsBus(port="/dev/null-armnet-test", motors=motors)
    try:
        got: dict[str, Any] | str = _bound_arguments(bus, method, args, kwargs)
    except RequestError as exc:
        assert exc.reply()["error_type"] == "TypeError"
        got = "TypeError"
    assert got == reference(bus, method, args, kwargs)


def test_cached_motor_facts_follow_a_recalibration(motors: dict[str, Any], calibration: dict[str, Any]) -> None:
    bus = FeetechMotorsBus(port="/dev/null-armnet-test", motors=motors, calibration=calibration)
    handle = Handle("FeetechMotorsBus", bus, DeviceLock("test"))
    first = _motor_facts(handle, ["elbow_flex", "gripper"])
    assert _motor_facts(handle, ["elbow_flex", "gripper"]) is first
    low = bus.calibration["gripper"].range_min
    bus.calibration["gripper"].range_min = low + 100  # edited in place
    edited = _motor_facts(handle, ["elbow_flex", "gripper"])
    assert edited is not first and edited["gripper"].bus_range is not None
    assert edited["gripper"].bus_range.range_min == low + 100
    bus.calibration = {m: dataclasses.replace(c, range_max=c.range_max - 1) for m, c in bus.calibration.items()}
    replaced = _motor_facts(handle, ["elbow_flex"])
    assert replaced["elbow_flex"].bus_range == dataclasses.replace(
        first["elbow_flex"].bus_range, range_max=first["elbow_flex"].bus_range.range_max - 1
    )

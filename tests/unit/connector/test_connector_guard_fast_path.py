"""The motion guard's fast paths decide exactly as the slow ones they replace.

``_bound_arguments`` must bind every call like ``inspect.Signature.bind`` on the
real LeRobot methods, the cached motor facts must follow a recalibration,
including one that edits a calibration entry in place, and the absolute rule's
proven interval must admit no goal the conversion to raw ticks would refuse.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
import random
from typing import Any

import pytest
from armnet_connector.config import MotorRange
from armnet_connector.errors import RequestError
from armnet_connector.hardware import DeviceLock, Handle
from armnet_connector.motion import (
    KEEPS_CALIBRATION,
    BadMotorValue,
    _bound_arguments,
    _goal_rules,
    _motor_facts,
    write_arguments,
)
from armnet_connector.safety import (
    DEGREES,
    RANGE_0_100,
    RANGE_M100_100,
    MotorFacts,
    MotorLimit,
    compile_limits,
    decide_goals,
    proven_inside,
    to_raw,
)
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


# -- the absolute rule's proven interval (safety.proven_inside) ----------------------

MODES = (DEGREES, RANGE_0_100, RANGE_M100_100)
#: Bus calibrations (the one a goal is converted with), including a narrow and a reversed one.
BUS_RANGES = (
    MotorRange(1, 1000, 3000, 0), MotorRange(1, 1000, 3000, 1), MotorRange(2, 0, 4095, 0),
    MotorRange(3, 2040, 2043, 1), MotorRange(4, 3000, 1000, 0),
)
#: The cell's raw bounds: inside, equal to and wider than the bus calibration, and tiny.
CELL_BOUNDS = ((1000, 3000), (1200, 2800), (0, 4095), (2041, 2042), (2000, 2001))


def _slow(limit: MotorLimit) -> MotorLimit:
    return dataclasses.replace(limit, inside=None)


def test_goals_in_the_proven_interval_convert_inside_the_calibrated_range() -> None:
    rng = random.Random(10)
    for mode in MODES:
        for bus in BUS_RANGES:
            for bounds in CELL_BOUNDS:
                inside = proven_inside(mode, bus, bounds)
                if inside is None:
                    continue
                edges = [inside[0], inside[1], math.nextafter(inside[0], math.inf), math.nextafter(inside[1], -math.inf)]
                for goal in edges + [rng.uniform(*inside) for _ in range(200)]:
                    assert bounds[0] <= to_raw(goal, mode, bus) <= bounds[1], (mode, bus, bounds, goal)


def test_the_proven_interval_covers_a_control_loops_goals() -> None:
    inside = proven_inside(DEGREES, MotorRange(1, 1000, 3000, 0), (1000, 3000))
    assert inside is not None and inside[0] < -80 and inside[1] > 80


def test_goal_checks_with_and_without_the_proven_interval_decide_alike() -> None:
    rng = random.Random(11)
    for mode in MODES:
        for bus in BUS_RANGES:
            for bounds in CELL_BOUNDS:
                facts = {"m": MotorFacts(mode, bus, MotorRange(9, *bounds, 0))}
                fast = compile_limits(facts, 5.0, normalize=True)
                slow = {m: _slow(rule) for m, rule in fast.items()}
                for _ in range(300):
                    goals = {"m": rng.uniform(-250.0, 250.0)}
                    present = {"m": goals["m"] + rng.uniform(-8.0, 8.0)}
                    for clamp in (False, True):
                        assert decide_goals(goals, present, fast, normalize=True, clamp=clamp) == decide_goals(
                            goals, present, slow, normalize=True, clamp=clamp
                        )


def test_raw_goal_checks_with_and_without_the_proven_interval_decide_alike() -> None:
    rng = random.Random(12)
    facts = {"m": MotorFacts(DEGREES, MotorRange(1, 1000, 3000, 0), MotorRange(1, 1200, 2800, 0))}
    fast = compile_limits(facts, None, normalize=False)
    slow = {m: _slow(rule) for m, rule in fast.items()}
    for _ in range(2000):
        goals = {"m": rng.choice([float(rng.randint(1100, 2900)), rng.uniform(1190.0, 2810.0)])}
        assert decide_goals(goals, {}, fast, normalize=False, clamp=False) == decide_goals(
            goals, {}, slow, normalize=False, clamp=False
        )


def test_compiled_goal_rules_follow_a_recalibration_of_the_bus(motors: dict[str, Any], calibration: dict[str, Any]) -> None:
    # A calibration job's write_calibration replaces bus.calibration: the proven interval
    # converting its goals must be rebuilt from the new calibration, never kept.
    bus = FeetechMotorsBus(port="/dev/null-armnet-test", motors=motors, calibration=calibration)
    cell = {m: MotorRange(c.id, c.range_min, c.range_max, c.drive_mode) for m, c in calibration.items()}
    handle = Handle("FeetechMotorsBus", bus, DeviceLock("test"), cell_ranges=cell)
    first = _goal_rules(handle, ["elbow_flex"], 10.0, True)[0]["elbow_flex"]
    assert first.inside is not None
    shifted = {m: dataclasses.replace(c, range_min=c.range_min + 300, range_max=c.range_max + 300)
               for m, c in bus.calibration.items()}
    bus.calibration = shifted
    after = _goal_rules(handle, ["elbow_flex"], 10.0, True)[0]["elbow_flex"]
    assert after.to_raw_range is not None and after.to_raw_range.range_min == shifted["elbow_flex"].range_min
    assert after.inside is not None and after.inside != first.inside
    low, high = after.inside
    for goal in (low, high):
        assert cell["elbow_flex"].range_min <= to_raw(goal, after.norm_mode, after.to_raw_range) <= cell["elbow_flex"].range_max


# -- goal values taken as they are (motion._write_values) ---------------------------


@pytest.mark.parametrize(
    ("raw", "expected"),
    [
        ({"gripper": 1.5, "elbow_flex": -2.0}, {"gripper": 1.5, "elbow_flex": -2.0}),
        ({"gripper": 1e308, "elbow_flex": 1e308}, {"gripper": 1e308, "elbow_flex": 1e308}),  # the sum overflows
        ({"gripper": 3, "elbow_flex": True}, {"gripper": 3.0, "elbow_flex": 1.0}),
        ({}, {}),
    ],
)
def test_goal_values_are_the_floats_the_job_sent(raw: dict[str, Any], expected: dict[str, float], motors: dict[str, Any]) -> None:
    handle = Handle("FeetechMotorsBus", FeetechMotorsBus(port="/dev/null-armnet-test", motors=motors), DeviceLock("test"))
    _name, values, _normalize = write_arguments(handle, "sync_write", ["Goal_Position", raw], {})
    assert values == expected and all(type(v) is float for v in values.values())


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_a_non_finite_goal_among_floats_is_refused(bad: float, motors: dict[str, Any]) -> None:
    handle = Handle("FeetechMotorsBus", FeetechMotorsBus(port="/dev/null-armnet-test", motors=motors), DeviceLock("test"))
    with pytest.raises(BadMotorValue) as refused:
        write_arguments(handle, "sync_write", ["Goal_Position", {"gripper": 1.0, "elbow_flex": bad}], {})
    assert refused.value.kind == "non_finite"


def test_lerobots_register_reads_and_writes_keep_the_calibration_and_the_motors(
    sim_cell, motors: dict[str, Any], calibration: dict[str, Any]
) -> None:
    """``motion.KEEPS_CALIBRATION``: the goal fast path trusts the motors' facts across these
    calls without comparing them again, so the installed LeRobot must never assign or edit a
    bus's calibration or its motors' norm modes in them (on the simulator, the real bus)."""
    bus = FeetechMotorsBus(port=sim_cell.arm.port, motors=motors, calibration=calibration)
    bus.connect(handshake=False)  # the calls, not the handshake, are under test (a loaded host drops replies)
    try:
        table, entries = bus.calibration, dict(bus.calibration)
        values = {m: dataclasses.astuple(c) for m, c in entries.items()}
        modes = {m: motor.norm_mode for m, motor in bus.motors.items()}
        present = bus.sync_read("Present_Position", num_retry=5)
        calls = {
            "sync_read": lambda: bus.sync_read("Present_Position", num_retry=5),
            "sync_write": lambda: bus.sync_write("Goal_Position", present),
            "read": lambda: bus.read("Present_Position", "elbow_flex", num_retry=5),
            "write": lambda: bus.write("Goal_Position", "elbow_flex", present["elbow_flex"], num_retry=5),
        }
        assert set(calls) == KEEPS_CALIBRATION
        for call in calls.values():
            call()
            assert bus.calibration is table and bus.calibration == entries
            assert all(bus.calibration[m] is entries[m] for m in entries)
            assert {m: dataclasses.astuple(c) for m, c in bus.calibration.items()} == values
            assert {m: motor.norm_mode for m, motor in bus.motors.items()} == modes
    finally:
        bus.disconnect(disable_torque=False)

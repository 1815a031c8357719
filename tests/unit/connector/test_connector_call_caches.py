"""What the bus path keeps between calls never lets a later call skip a check.

The connector keeps, per call shape, how a call binds (``motion._bound_arguments``),
per handle the goal screen of the motors last written (``safety.GoalScreen``), decides
a control loop's goal write in one step when all of that is current
(``MotionGuard._accepts_plain_goals``), and takes a plain call's arguments as parsed
(``wire.plain_arguments``); the proxy keeps
its method proxies on the instance and sends a live object's calls directly. Each
test warms a cache with a good call, then sends a call of another shape, a value
outside the limits or a tagged value, and checks it is decided as without the cache.
"""

from __future__ import annotations

import math
import random
import time
from typing import Any

import pytest
from armnet_connector.allowlist import CALIBRATION_METHODS
from armnet_connector.cell import Counters
from armnet_connector.config import ArmConfig, MotorRange
from armnet_connector.errors import RequestError
from armnet_connector.hardware import DeviceLock, Handle
from armnet_connector.interlock import Interlock
from armnet_connector.motion import MotionGuard, _bound_arguments
from armnet_connector.safety import (
    DEGREES,
    RANGE_0_100,
    GoalScreen,
    MotorFacts,
    compile_limits,
    decide_goals,
)
from armnet_runtime.errors import InterlockTripped, SafetyViolation
from armnet_runtime.wire import TAG, decode, plain_arguments
from lerobot.motors.feetech import FeetechMotorsBus

pytestmark = pytest.mark.unit


# -- the binding kept per call shape --------------------------------------------------


def test_a_cached_binding_never_admits_a_call_of_another_shape(motors: dict[str, Any]) -> None:
    bus = FeetechMotorsBus(port="/dev/null-armnet-test", motors=motors)
    good = ["Goal_Position", {"gripper": 1.0}]
    assert _bound_arguments(bus, "sync_write", good, {}) == {"data_name": "Goal_Position", "values": {"gripper": 1.0}}
    for args, kwargs in (
        (["Goal_Position", {"gripper": 1.0}, True], {}),  # normalize is keyword-only
        (["Goal_Position"], {}),  # values missing
        (["Goal_Position", {}], {"data_name": "Lock"}),  # given twice
        (["Goal_Position", {}], {"bogus": 1}),
    ):
        with pytest.raises(RequestError) as refused:
            _bound_arguments(bus, "sync_write", args, kwargs)
        assert refused.value.reply()["error_type"] == "TypeError"
    # The same shape again binds this call's values, not the first call's.
    assert _bound_arguments(bus, "sync_write", ["Lock", 0], {"normalize": False}) == {
        "data_name": "Lock", "values": 0, "normalize": False,
    }
    assert _bound_arguments(bus, "sync_write", ["Torque_Enable", {"gripper": 0}], {})["data_name"] == "Torque_Enable"


# -- the goal screen -------------------------------------------------------------------


def _limits(rng: random.Random) -> dict[str, Any]:
    facts = {}
    for index, motor in enumerate(("a", "b", "c")):
        low = rng.randint(500, 1800)
        high = low + rng.randint(3, 2000)
        bus_range = MotorRange(index + 1, low - rng.randint(0, 300), high + rng.randint(0, 300), rng.randint(0, 1))
        facts[motor] = MotorFacts(rng.choice((DEGREES, RANGE_0_100)), bus_range, MotorRange(index + 1, low, high, 0))
    limit = rng.choice((None, 3.0, {"a": 2.0, "c": 8.0}))
    return compile_limits(facts, limit, normalize=True)


def test_the_goal_screen_accepts_only_writes_decide_goals_accepts_unchanged() -> None:
    rng = random.Random(20)
    accepted = 0
    for _ in range(3000):
        limits = _limits(rng)
        screen = GoalScreen.build(("a", "b", "c"), limits)
        goals = {m: rng.uniform(-120.0, 120.0) for m in ("a", "b", "c")}
        present = {m: goal + rng.choice((0.0, rng.uniform(-10.0, 10.0))) for m, goal in goals.items()}
        if rng.random() < 0.05:
            present["b"] = math.nan
        for clamp in (False, True):
            decision = decide_goals(goals, present, limits, normalize=True, clamp=clamp)
            sizes = screen.step_sizes(goals, present) if screen is not None else None
            if sizes is not None:
                accepted += 1
                assert decision.violation is None and decision.clamped == () and decision.goals == goals
                assert dict(zip(screen.motors, sizes, strict=True)) == {m: abs(v) for m, v in decision.steps.items()}
    assert accepted > 50  # the screen does take writes (the usual one: the next test)


def test_the_goal_screen_declines_what_it_cannot_vouch_for() -> None:
    facts = {m: MotorFacts(DEGREES, MotorRange(1, 1000, 3000, 0), MotorRange(1, 1000, 3000, 0)) for m in ("a", "b")}
    limits = compile_limits(facts, 5.0, normalize=True)
    screen = GoalScreen.build(("a", "b"), limits)
    assert screen is not None
    assert screen.step_sizes({"a": 1.0, "b": -2.0}, {"a": 0.0, "b": 0.0}) == (1.0, 2.0)
    assert screen.step_sizes({"a": 1.0, "b": 9.0}, {"a": 0.0, "b": 0.0}) is None  # a step over the limit
    assert screen.step_sizes({"a": 1.0, "b": 170.0}, {"a": 0.0, "b": 168.0}) is None  # outside the calibrated range
    assert screen.step_sizes({"a": 1.0}, {"a": 0.0, "b": 0.0}) is None  # another motor list
    assert screen.step_sizes({"a": 1.0, "x": 0.0}, {"a": 0.0, "x": 0.0}) is None
    assert screen.step_sizes({"a": 1.0, "b": 2.0}, {"a": 0.0}) is None  # a position unknown
    assert screen.step_sizes({"a": 1.0, "b": math.nan}, {"a": 0.0, "b": 0.0}) is None
    assert GoalScreen.build(("a", "x"), limits) is None  # not a motor of the bus


# -- the one-step goal write (MotionGuard._accepts_plain_goals) ---------------------------


def _guard_and_handle(motors: dict[str, Any], calibration: dict[str, Any]) -> tuple[MotionGuard, Handle]:
    bus = FeetechMotorsBus(port="/dev/null-armnet-test", motors=motors, calibration=calibration)
    cell = {m: MotorRange(c.id, c.range_min, c.range_max, c.drive_mode) for m, c in calibration.items()}
    handle = Handle(
        "FeetechMotorsBus", bus, DeviceLock("test"), arm_config=ArmConfig(port="/dev/null", safety_limit=5.0),
        cell_ranges=cell,
    )
    guard = MotionGuard(Interlock(), present_max_age_s=60.0, counters=Counters(), policy="trip")
    return guard, handle


def _middle(calibration: dict[str, Any]) -> dict[str, float]:
    return dict.fromkeys(calibration, 0.0) | {"gripper": 50.0}


def test_the_one_step_goal_write_takes_only_what_the_long_way_accepts(motors, calibration) -> None:
    guard, handle = _guard_and_handle(motors, calibration)
    present = _middle(calibration)
    handle.present[True] = (time.monotonic(), dict(present))
    assert not guard._accepts_plain_goals(handle, ["Goal_Position", dict(present)])  # nothing compiled yet
    guard.check(handle, "sync_write", ["Goal_Position", dict(present)], {})  # the long way compiles
    assert guard._accepts_plain_goals(handle, ["Goal_Position", {**present, "elbow_flex": 1.0}])
    declined = (
        ["Goal_Position", {**present, "elbow_flex": 9.0}],  # a step over the limit
        ["Goal_Position", {**present, "elbow_flex": math.nan}],
        ["Goal_Position", {**present, "elbow_flex": 1}],  # an int: the long way converts it
        ["Goal_Position", {"elbow_flex": 1.0}],  # another motor list: other rules
        ["Goal_Position", {**present, "nope": 1.0}],  # not a motor of the bus
        ["Lock", dict(present)],
        [["Goal_Position"], dict(present)],
        ["Goal_Position", dict(present), True],
    )
    for args in declined:
        assert not guard._accepts_plain_goals(handle, args), args
    with pytest.raises(RequestError) as refused:  # and check decides the step over the limit the long way
        guard.check(handle, "sync_write", ["Goal_Position", {**present, "elbow_flex": 9.0}], {})
    assert refused.value.reply()["error_type"] == "SafetyViolation" and guard.interlock.tripped
    assert not guard._accepts_plain_goals(handle, ["Goal_Position", dict(present)])  # the interlock holds
    with pytest.raises(RequestError):
        guard.check(handle, "sync_write", ["Goal_Position", dict(present)], {})


@pytest.mark.parametrize("method", sorted(CALIBRATION_METHODS["FeetechMotorsBus"] | {"connect", "read_calibration"}))
def test_the_one_step_goal_write_follows_a_recalibration_and_stale_positions(motors, calibration, method) -> None:
    guard, handle = _guard_and_handle(motors, calibration)
    handle.allow_calibration = True
    present = _middle(calibration)
    handle.present[True] = (time.monotonic(), dict(present))
    guard.check(handle, "sync_write", ["Goal_Position", dict(present)], {})
    assert guard._accepts_plain_goals(handle, ["Goal_Position", dict(present)])
    # A call that may recalibrate (anything but KEEPS_CALIBRATION), which edits the calibration
    # in place: the one-step path no longer vouches for the facts; the long way compares by value.
    guard.check(handle, method, [dict(calibration)] if method == "write_calibration" else [], {})
    handle.obj.calibration["elbow_flex"].range_min += 10
    assert not guard._accepts_plain_goals(handle, ["Goal_Position", dict(present)])
    guard.check(handle, "sync_write", ["Goal_Position", dict(present)], {})  # the long way rebuilds the rules
    assert guard._accepts_plain_goals(handle, ["Goal_Position", dict(present)])
    handle.present[True] = (time.monotonic() - 120.0, dict(present))  # this tick's read is too old
    assert not guard._accepts_plain_goals(handle, ["Goal_Position", dict(present)])


def test_facts_whose_comparison_raises_stay_untrusted_by_the_one_step_goal_write(motors, calibration) -> None:
    """A calibration of odd values (here an array id) makes the long way's comparison raise:
    every later write must take the long way and raise again, never the old facts' fast path."""
    import numpy as np

    guard, handle = _guard_and_handle(motors, calibration)
    present = _middle(calibration)
    handle.present[True] = (time.monotonic(), dict(present))
    guard.check(handle, "sync_write", ["Goal_Position", dict(present)], {})
    assert guard._accepts_plain_goals(handle, ["Goal_Position", dict(present)])
    guard.check(handle, "read_calibration", [], {})
    handle.obj.calibration["shoulder_pan"].id = np.array([1, 1])
    for _ in range(2):
        with pytest.raises(ValueError, match="ambiguous"):
            guard.check(handle, "sync_write", ["Goal_Position", dict(present)], {})
        assert not guard._accepts_plain_goals(handle, ["Goal_Position", dict(present)])


@pytest.mark.parametrize(
    ("method", "args"),
    [("sync_write", ["Goal_Position", {1: 0.0}]), ("write", ["Goal_Position", 1, 0.0])],
)
def test_a_goal_keyed_by_anything_but_a_motor_name_is_refused(motors, calibration, method, args) -> None:
    guard, handle = _guard_and_handle(motors, calibration)
    handle.present[True] = (time.monotonic(), _middle(calibration))
    with pytest.raises(RequestError) as refused:
        guard.check(handle, method, args, {})
    assert refused.value.reply()["error_type"] == "TypeError" and "motor name" in refused.value.message


# -- the arguments taken as parsed ------------------------------------------------------


@pytest.mark.parametrize(
    ("items", "plain"),
    [
        (["Goal_Position", {"a": 1.0, "b": 2}], True),
        (["Present_Position"], True),
        ([], True),
        (["Goal_Position", {"a": {TAG: "float", "value": "nan"}}], False),
        (["Goal_Position", {TAG: "tuple", "items": []}], False),
        ([[1, 2]], False),
        (["Goal_Position", {"a": [1.0]}], False),
    ],
)
def test_plain_arguments_are_exactly_those_decode_leaves_as_they_are(items: list[Any], plain: bool) -> None:
    assert plain_arguments(items) is plain
    if plain:
        assert decode(items) == items


# -- through the connector: every check after warm caches -------------------------------


def _warm(bus: Any) -> dict[str, float]:
    present = bus.sync_read("Present_Position")
    for _ in range(3):
        bus.sync_write("Goal_Position", dict(present))
    return present


def test_after_cached_goal_writes_a_step_over_the_limit_is_refused_and_trips(bus, sim_cell, connector) -> None:
    present = _warm(bus)
    assert "sync_write" in bus.__dict__  # the proxy's method is kept on the instance
    before = sim_cell.arm.goal_positions()
    with pytest.raises(SafetyViolation):
        bus.sync_write("Goal_Position", {**present, "elbow_flex": present["elbow_flex"] + 45.0})
    assert sim_cell.arm.goal_positions() == before
    assert connector.interlock.tripped
    with pytest.raises(InterlockTripped):  # and the interlock holds for the next, cached-shape write
        bus.sync_write("Goal_Position", dict(present))


def test_after_cached_goal_writes_another_shape_is_still_checked(bus, sim_cell, connector) -> None:
    present = _warm(bus)
    # Fewer motors (another screen), then a tagged non-finite goal (not plain arguments).
    bus.sync_write("Goal_Position", {"elbow_flex": present["elbow_flex"] + 1.0})
    with pytest.raises(ValueError):
        bus.sync_write("Goal_Position", {**present, "gripper": math.inf})
    assert connector.interlock.tripped  # a non-finite goal trips, as any refused goal


def test_after_cached_goal_writes_a_goal_outside_the_range_is_refused(bus, sim_cell, connector) -> None:
    present = _warm(bus)
    raw = bus.sync_read("Present_Position", normalize=False)
    bus.sync_write("Goal_Position", raw, normalize=False)  # another binding shape, inside the range
    with pytest.raises(SafetyViolation):
        bus.sync_write("Goal_Position", {**raw, "elbow_flex": 10_000}, normalize=False)
    assert connector.interlock.tripped
    del present


def test_a_lost_connection_under_a_cached_method_is_recovered(bus, connector) -> None:
    bus.sync_read("Present_Position")
    bus._conn._sock.close()  # the connection breaks under the proxy (say the connector restarted)
    time.sleep(0.05)
    assert set(bus.sync_read("Present_Position")) == set(bus.motors)


def test_in_the_grace_window_a_register_write_is_told_the_job_is_shutting_down(bus, sim_cell, connector) -> None:
    """Whichever path a write takes once the deadline tripped the interlock, the job hears why: its grace window."""
    from armnet_connector.interlock import TripReason
    from armnet_runtime.errors import ShuttingDown

    _warm(bus)
    connector.interlock.trip(TripReason.DEADLINE, "the job's timeout passed")
    with pytest.raises(ShuttingDown, match="grace window"):
        bus.write("Torque_Enable", "shoulder_pan", 1, normalize=False)
    bus.write("Torque_Enable", "shoulder_pan", 0, normalize=False)  # letting go is still accepted

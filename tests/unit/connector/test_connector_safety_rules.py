"""The pure safety rules: LeRobot max_relative_target semantics and calibrated absolute limits."""

from __future__ import annotations

import pytest
from armnet_connector.config import MotorRange
from armnet_connector.safety import (
    DEGREES,
    RANGE_0_100,
    RANGE_M100_100,
    MotorFacts,
    RestWalk,
    check_goal_write,
    is_release_write,
    limit_for,
    to_raw,
)

pytestmark = pytest.mark.unit

RANGE = MotorRange(id=1, range_min=1000, range_max=3000)
FACTS = {"elbow": MotorFacts(DEGREES, RANGE, RANGE), "gripper": MotorFacts(RANGE_0_100, RANGE, RANGE)}


def test_a_step_within_the_relative_limit_is_allowed() -> None:
    assert check_goal_write({"elbow": 9.0}, {"elbow": 0.0}, FACTS, 10.0, normalize=True) is None


def test_a_step_beyond_the_relative_limit_names_motor_step_and_limit() -> None:
    violation = check_goal_write({"elbow": -12.5}, {"elbow": 0.0}, FACTS, 10.0, normalize=True)
    assert violation is not None
    assert (violation.motor, violation.kind, violation.step, violation.limit) == ("elbow", "relative", -12.5, 10.0)
    assert "elbow" in violation.message() and "10.000" in violation.message()


def test_a_per_motor_limit_applies_only_to_its_motor() -> None:
    limits = {"gripper": 5.0}
    assert limit_for(limits, "elbow") is None
    assert check_goal_write({"elbow": 50.0}, {"elbow": 0.0}, FACTS, limits, normalize=True) is None
    violation = check_goal_write({"gripper": 56.0}, {"gripper": 50.0}, FACTS, limits, normalize=True)
    assert violation is not None and violation.motor == "gripper"


def test_no_relative_limit_means_only_the_absolute_range_is_checked() -> None:
    assert check_goal_write({"elbow": 80.0}, {}, FACTS, None, normalize=True) is None


def test_a_raw_write_has_its_limit_converted_to_ticks() -> None:
    # 10 degrees is about 113.75 ticks on an STS3215.
    assert check_goal_write({"elbow": 2110}, {"elbow": 2000}, FACTS, 10.0, normalize=False) is None
    assert check_goal_write({"elbow": 2120}, {"elbow": 2000}, FACTS, 10.0, normalize=False) is not None


def test_a_degrees_goal_outside_the_calibrated_range_is_refused() -> None:
    # middle 2000, so +100 degrees is 2000 + 1137 = 3137 > 3000.
    violation = check_goal_write({"elbow": 100.0}, {}, FACTS, None, normalize=True)
    assert violation is not None and violation.kind == "absolute" and violation.bounds == (1000, 3000)


def test_a_raw_goal_outside_the_calibrated_range_is_refused() -> None:
    assert check_goal_write({"elbow": 999}, {}, FACTS, None, normalize=False) is not None
    assert check_goal_write({"elbow": 1000}, {}, FACTS, None, normalize=False) is None


def test_a_customer_calibration_cannot_widen_the_cells_range() -> None:
    wide = MotorRange(id=1, range_min=0, range_max=4095)
    facts = {"elbow": MotorFacts(RANGE_M100_100, wide, RANGE)}
    # -100 in the customer's wide calibration is raw 0, below the cell's 1000.
    assert check_goal_write({"elbow": -100.0}, {}, facts, None, normalize=True) is not None


def test_motors_unknown_to_the_bus_are_left_to_the_real_call() -> None:
    assert check_goal_write({"nope": 1e9}, {}, FACTS, 1.0, normalize=True) is None


@pytest.mark.parametrize(
    ("mode", "value", "expected"),
    [(DEGREES, 10.0, 2113), (RANGE_0_100, 50.0, 2000), (RANGE_M100_100, -100.0, 1000), (RANGE_M100_100, 250.0, 3000)],
)
def test_to_raw_matches_lerobots_unnormalize(mode: str, value: float, expected: int) -> None:
    assert to_raw(value, mode, RANGE) == expected


def test_drive_mode_inverts_range_modes() -> None:
    inverted = MotorRange(id=1, range_min=1000, range_max=3000, drive_mode=1)
    assert to_raw(-100.0, RANGE_M100_100, inverted) == 3000


def test_only_torque_off_is_a_release_write() -> None:
    assert is_release_write("Torque_Enable", {"a": 0, "b": 0})
    assert not is_release_write("Lock", {"a": 0})  # unlocking the EEPROM is not letting go
    assert not is_release_write("Torque_Enable", {"a": 1})
    assert not is_release_write("Goal_Position", {"a": 0})


def test_a_rest_walk_lasts_its_distance_over_its_speed_and_ends_at_the_goal() -> None:
    walk = RestWalk({"a": 1000, "b": 2000}, {"a": 2000, "b": 1990}, 500)
    assert walk.seconds == 2.0
    assert walk.at(0.0) == {"a": 1000, "b": 2000}
    assert walk.at(0.5) == {"a": 1500, "b": 1995}
    assert walk.at(1.0) == walk.at(7.0) == {"a": 2000, "b": 1990}


def _ticks(walk: RestWalk, gaps: list[float]) -> list[tuple[float, float]]:
    """(time, fraction done) after each tick, ticks ``gaps`` seconds apart."""
    at, done, seen = 0.0, 0.0, [(0.0, 0.0)]
    for gap in gaps:
        at += gap
        done = walk.advance(done, gap)
        seen.append((at, done))
    return seen


def test_late_ticks_do_not_stretch_a_rest_walk() -> None:
    """Each tick advances by the time that really passed: 70 ms ticks end the walk on time."""
    walk = RestWalk({"a": 0}, {"a": 1000}, 1000)
    seen = _ticks(walk, [0.07] * 20)
    finished = next(at for at, done in seen if done >= 1.0)
    assert finished <= walk.seconds + 0.07


def test_after_a_stall_a_rest_walk_never_moves_faster_than_its_speed_limit() -> None:
    """A stall costs time, never speed: over any stretch of ticks, at most the limit plus one step."""
    walk = RestWalk({"a": 0}, {"a": 1000}, 1000, max_step_s=0.1)
    gaps = [0.02] * 10 + [3.0] + [0.02] * 60  # the host froze for 3 s mid-walk
    seen = _ticks(walk, gaps)
    for i, (t0, d0) in enumerate(seen):
        for t1, d1 in seen[i + 1:]:
            moved_ticks = (d1 - d0) * 1000
            assert moved_ticks <= 1000 * (t1 - t0) + 1000 * walk.max_step_s + 1e-6
    assert seen[11][1] - seen[10][1] == pytest.approx(0.1)  # the stall's tick: one step, not 3 s of motion


def test_a_rest_walk_from_the_goal_is_done_at_once() -> None:
    walk = RestWalk({"a": 5}, {"a": 5}, 10)
    assert walk.seconds == 0.0 and walk.advance(0.0, 0.0) == 1.0 and walk.at(1.0) == {"a": 5}

"""Usage: cell time held, decayed with a half-life, and the cell-hours spent in the current period."""

from __future__ import annotations

import math
from datetime import UTC, datetime, timedelta

import pytest
from armnet_operator.quota import (
    QuotaPeriod,
    Usage,
    accrue_usage,
    credits_left,
    decay,
    period_start,
)
from operator_builders import NOW, a_quota

pytestmark = pytest.mark.unit

HOUR = timedelta(hours=1)


def test_usage_halves_every_half_life():
    assert decay(800.0, 3 * HOUR, HOUR) == 100.0


def test_a_zero_half_life_never_forgets():
    assert decay(800.0, 3 * HOUR, timedelta(0)) == 800.0


def test_the_first_accrual_only_starts_the_clock():
    assert accrue_usage(Usage(), 3, NOW, HOUR) == Usage(0.0, 0.0, None, NOW)


def test_one_cell_held_for_one_half_life_adds_its_decayed_cell_seconds():
    after = accrue_usage(Usage(updated_at=NOW), 1, NOW + HOUR, HOUR)
    assert after.decayed_cell_seconds == pytest.approx(3600 / math.log(2) / 2)
    assert after.period_cell_seconds == 3600


def test_usage_decays_while_no_cell_is_held():
    after = accrue_usage(Usage(1000.0, updated_at=NOW), 0, NOW + 2 * HOUR, HOUR)
    assert after.decayed_cell_seconds == pytest.approx(250.0)


def test_accruing_in_two_steps_equals_one_step():
    start = Usage(500.0, updated_at=NOW)
    once = accrue_usage(start, 2, NOW + 3 * HOUR, HOUR)
    twice = accrue_usage(accrue_usage(start, 2, NOW + HOUR, HOUR), 2, NOW + 3 * HOUR, HOUR)
    assert twice.decayed_cell_seconds == pytest.approx(once.decayed_cell_seconds)


def test_a_clock_that_steps_back_changes_nothing():
    usage = Usage(500.0, 20.0, None, NOW)
    assert accrue_usage(usage, 4, NOW - HOUR, HOUR) is usage


def test_a_week_starts_on_monday_at_midnight_utc():
    assert period_start(datetime(2026, 1, 8, 15, 30, tzinfo=UTC), QuotaPeriod.WEEK) == datetime(2026, 1, 5, tzinfo=UTC)
    assert period_start(datetime(2026, 1, 8, 15, 30, tzinfo=UTC), QuotaPeriod.DAY) == datetime(2026, 1, 8, tzinfo=UTC)


def test_the_period_count_restarts_at_the_boundary_and_counts_only_time_after_it():
    before_midnight = datetime(2026, 1, 1, 23, 0, tzinfo=UTC)
    usage = accrue_usage(Usage(updated_at=before_midnight), 0, before_midnight, HOUR, QuotaPeriod.DAY)
    usage = Usage(usage.decayed_cell_seconds, 5000.0, usage.period_start, usage.updated_at)
    after = accrue_usage(usage, 2, datetime(2026, 1, 2, 0, 30, tzinfo=UTC), HOUR, QuotaPeriod.DAY)
    assert after.period_start == datetime(2026, 1, 2, tzinfo=UTC)
    assert after.period_cell_seconds == 2 * 1800


def test_credits_left_are_the_period_grant_minus_what_was_spent_in_it():
    quota = a_quota("team-a").with_credits(2.0, QuotaPeriod.DAY).build()
    spent = Usage(period_cell_seconds=1800, period_start=period_start(NOW, QuotaPeriod.DAY), updated_at=NOW)
    assert credits_left(quota, spent, NOW) == 2 * 3600 - 1800
    assert credits_left(quota, spent, NOW + timedelta(days=1)) == 2 * 3600
    assert credits_left(a_quota("team-a").build(), spent, NOW) is None

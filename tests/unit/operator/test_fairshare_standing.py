"""A quota's standing, as its status shows it: cells held, borrowed, jobs waiting, usage accrued."""

from __future__ import annotations

from datetime import timedelta

import pytest
from armnet_operator.fairshare import Standing, plan_standings
from armnet_operator.quota import Usage
from armnet_operator.quota_parsing import parse_usage, standing_status
from operator_builders import NOW, a_cell, a_job, a_quota

pytestmark = pytest.mark.unit

QUOTAS = [a_quota("team-a").nominal(1).in_cohort("lab").build(), a_quota("team-b").nominal(3).in_cohort("lab").build()]


def holding(namespace: str, name: str, cell: str):
    job = a_job().named(name, namespace).running_on(cell)
    return job, a_cell().named(cell).claimed_by(job).ready()


def test_a_standing_counts_cells_held_borrowed_and_jobs_waiting():
    (j1, c1), (j2, c2) = holding("team-a", "a1", "c1"), holding("team-a", "a2", "c2")
    waiting = a_job().named("a3", "team-a").queued()
    standings = plan_standings([j1, j2, waiting], [c1, c2], QUOTAS, {}, NOW)
    assert (standings["team-a-so101"].cells_in_use, standings["team-a-so101"].borrowed_cells,
            standings["team-a-so101"].waiting_jobs) == (2, 1, 1)
    assert standings["team-b-so101"] == Standing(0, 0, 0, Usage(0.0, 0.0, None, NOW))


def test_usage_accrues_for_the_cells_held_since_the_last_write():
    job, cell = holding("team-a", "a1", "c1")
    last = {"team-a-so101": Usage(0.0, 0.0, None, NOW - timedelta(minutes=10))}
    usage = plan_standings([job], [cell], QUOTAS, last, NOW)["team-a-so101"].usage
    assert usage.period_cell_seconds == 600 and 0 < usage.decayed_cell_seconds <= 600


def test_a_standing_round_trips_through_the_status():
    standing = Standing(2, 1, 4, Usage(12.5, 30.0, None, NOW))
    status = standing_status(standing)
    assert (status["cellsInUse"], status["borrowedCells"], status["waitingJobs"]) == (2, 1, 4)
    assert parse_usage({"status": status}) == standing.usage

"""``status.arrivedAt``: jobs created in one second wait in the order they arrived, and stay put.

A creation time has whole seconds. Ordered by namespace and name among them, each late
arrival moved the jobs of its second already numbered one place back, and during a
burst the operator rewrote the same positions again and again (``bench/burst.py``).
"""

from __future__ import annotations

from datetime import timedelta

import pytest
from armnet_core.times import parse_time
from armnet_operator.model import Timing
from armnet_operator.reconcile import Limits, Memory, reconcile_once
from operator_world import World

pytestmark = pytest.mark.unit

TIMING = Timing(heartbeat_timeout=timedelta(seconds=30), claim_grace=timedelta(seconds=5))
LIMITS = Limits(position_refresh=timedelta(seconds=0))  # positions at once: any rewrite would show


def one_pass(world: World, memory: Memory) -> None:
    world.heartbeat("c0")
    jobs, cells = world.snapshot()
    reconcile_once(jobs, cells, world.now, TIMING, world, memory, LIMITS)


def test_a_late_arrival_of_the_same_second_queues_behind_and_moves_no_one() -> None:
    world, memory = World(), Memory()
    world.add_cell("c0", "so-101", None)
    world.submit("run", "so-101", None, 0)
    one_pass(world, memory)  # binds: c0 is busy from here on
    world.tick(0.1)
    world.submit("zed", "so-101", None, 0)
    one_pass(world, memory)
    zed = world.jobs["t/zed"]
    assert zed["status"]["queuePosition"] == 1
    arrived = parse_time(zed["status"]["arrivedAt"])
    assert arrived == world.now and arrived.microsecond == 100_000  # microseconds, unlike creation
    version = zed["metadata"]["resourceVersion"]

    world.tick(0.3)
    world.submit("abe", "so-101", None, 0)  # the same creation second, a name before zed's
    assert world.jobs["t/abe"]["metadata"]["creationTimestamp"] == zed["metadata"]["creationTimestamp"]
    one_pass(world, memory)
    assert world.jobs["t/abe"]["status"]["queuePosition"] == 2
    assert zed["metadata"]["resourceVersion"] == version  # not rewritten: its place held
    world.tick(1)
    one_pass(world, memory)
    assert zed["status"]["arrivedAt"] == world.jobs["t/zed"]["status"]["arrivedAt"]
    assert (zed["status"]["queuePosition"], world.jobs["t/abe"]["status"]["queuePosition"]) == (1, 2)
    assert zed["metadata"]["resourceVersion"] == version

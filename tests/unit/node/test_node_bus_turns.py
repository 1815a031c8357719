"""Probe and launch take turns on a cell's bus (a probe overlapping a job's start is never kept)."""

from __future__ import annotations

import threading

import pytest
from armnet_node.bus_turns import BusTurns

pytestmark = pytest.mark.unit


def test_a_launch_waits_for_a_probe_under_way_to_finish_reading() -> None:
    turns = BusTurns()
    reading, release = threading.Event(), threading.Event()
    order: list[str] = []

    def read() -> str:
        reading.set()
        release.wait(5)
        order.append("probe read")
        return "idle facts"

    prober = threading.Thread(target=lambda: turns.probe(read, bus_held=lambda: False))
    prober.start()
    assert reading.wait(5)

    def launch() -> None:
        with turns.launching():
            order.append("launch")

    launcher = threading.Thread(target=launch)
    launcher.start()
    launcher.join(0.2)
    assert launcher.is_alive(), "the launch step must not start while the probe reads the bus"
    release.set()
    prober.join(5)
    launcher.join(5)
    assert order == ["probe read", "launch"]


def test_a_probe_waits_for_the_launch_step_then_reads_nothing_once_the_job_holds_the_bus() -> None:
    turns = BusTurns()
    runner: list[str] = []
    reads: list[str] = []
    in_launch, finish_launch = threading.Event(), threading.Event()
    results: list[str | None] = []

    def launch() -> None:
        with turns.launching():
            in_launch.set()
            finish_launch.wait(5)
            runner.append("job")

    launcher = threading.Thread(target=launch)
    launcher.start()
    assert in_launch.wait(5)
    prober = threading.Thread(
        target=lambda: results.append(turns.probe(lambda: reads.append("read") or "facts", bus_held=lambda: bool(runner)))
    )
    prober.start()
    prober.join(0.2)
    assert prober.is_alive(), "the probe must not read the bus during the launch step"
    finish_launch.set()
    launcher.join(5)
    prober.join(5)
    assert results == [None] and reads == []


def test_an_idle_bus_is_read_and_the_result_kept() -> None:
    assert BusTurns().probe(lambda: "facts", bus_held=lambda: False) == "facts"

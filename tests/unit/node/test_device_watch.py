"""The device watch reads real paths (a symlink to a character device) and is the device plugin's health too."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest
from armnet_node.device_health import DEBOUNCE_S, DeviceState
from armnet_node.device_watch import FAILURE_LOG_EVERY_S, DeviceWatch
from armnet_node.deviceplugin.decide import HEALTHY, UNHEALTHY, DevicePath, cell_device_paths
from armnet_node.deviceplugin.server import CellPlugin
from armnet_node.metrics import AgentMetrics

pytestmark = pytest.mark.unit


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def watched(tmp_path: Path) -> tuple[DeviceWatch, Path, Clock, list[DeviceState], AgentMetrics]:
    link = tmp_path / "usb-arm"
    link.symlink_to("/dev/null")  # a character device every host has
    clock, changes, metrics = Clock(), [], AgentMetrics()
    watch = DeviceWatch("cell-a", lambda: cell_device_paths({"arm": str(link)}), changes.append, metrics,
                        clock=clock)
    return watch, link, clock, changes, metrics


def gauge(metrics: AgentMetrics) -> float | None:
    return metrics.registry.get_sample_value("armnet_agent_device_healthy", {"cell": "cell-a"})


def test_a_removed_symlink_is_lost_after_the_debounce_and_reported_once(tmp_path: Path) -> None:
    watch, link, clock, changes, metrics = watched(tmp_path)
    watch.poll()
    link.unlink()
    clock.now = 0.5
    watch.poll()
    assert not watch.state.lost and gauge(metrics) == 1.0
    clock.now = 0.5 + DEBOUNCE_S
    watch.poll()
    watch.poll()
    assert watch.state.lost and gauge(metrics) == 0.0
    assert [c.lost for c in changes] == [False, True]  # the first problem, then the verdict; not again
    assert str(link) in watch.state.problems[0]


def test_the_link_put_back_is_present_at_the_next_read_and_healthy_once_it_stayed(tmp_path: Path) -> None:
    watch, link, clock, changes, metrics = watched(tmp_path)
    watch.poll()
    link.unlink()
    for clock.now in (0.5, 0.5 + DEBOUNCE_S):
        watch.poll()
    link.symlink_to("/dev/null")
    clock.now = 3.0
    watch.poll()
    assert not watch.state.problems and watch.state.lost and gauge(metrics) == 0.0
    clock.now = 3.0 + DEBOUNCE_S
    watch.poll()
    assert watch.state == DeviceState(seen_ok=True) and gauge(metrics) == 1.0 and not changes[-1].lost


def test_a_plain_file_behind_the_link_is_not_a_device(tmp_path: Path) -> None:
    watch, link, clock, _, _ = watched(tmp_path)
    watch.poll()
    link.unlink()
    (tmp_path / "file").write_text("")
    link.symlink_to(tmp_path / "file")
    for clock.now in (0.5, 0.5 + DEBOUNCE_S):
        watch.poll()
    assert watch.state.lost and "is not a character device" in watch.state.problems[0]


def test_the_device_plugin_reports_the_watchs_verdict_not_its_own_read(tmp_path: Path) -> None:
    watch, link, clock, _, metrics = watched(tmp_path)
    plugin = CellPlugin("cell-a", lambda: cell_device_paths({"arm": str(link)}), metrics, tmp_path,
                        health_source=watch.plugin_health)
    watch.poll()
    link.unlink()
    clock.now = 0.5
    watch.poll()
    assert plugin.health() == HEALTHY  # a blink so far: the Cell, the job and the kubelet all wait
    clock.now = 0.5 + DEBOUNCE_S
    watch.poll()
    assert plugin.health() == UNHEALTHY


def test_stopping_the_watch_removes_its_cells_series(tmp_path: Path) -> None:
    watch, _, _, _, metrics = watched(tmp_path)
    watch.start()
    watch.stop()
    assert gauge(metrics) is None


def failing_watch(clock: Clock) -> DeviceWatch:
    def paths() -> tuple[DevicePath, ...]:
        raise RuntimeError("a bug behind the cell's paths")

    return DeviceWatch("cell-a", paths, lambda _state: None, AgentMetrics(), clock=clock)


def test_a_read_that_keeps_failing_logs_its_traceback_at_most_once_a_minute(caplog: pytest.LogCaptureFixture) -> None:
    clock = Clock()
    watch = failing_watch(clock)
    with caplog.at_level(logging.WARNING, logger="armnet_node.device_watch"):
        for clock.now in (0.0, 0.5, 1.0, 59.5):
            watch.tick()
        assert len(caplog.records) == 1 and caplog.records[0].exc_info is not None
        clock.now = FAILURE_LOG_EVERY_S
        watch.tick()
    assert len(caplog.records) == 2 and "3 more failures" in caplog.records[1].getMessage()


def test_starting_a_watch_whose_read_fails_does_not_raise() -> None:
    watch = failing_watch(Clock())
    try:
        assert watch.start().state == DeviceState()
    finally:
        watch.stop()

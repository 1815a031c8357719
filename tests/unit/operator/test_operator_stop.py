"""Stopping the reconcile loop: the pass in flight ends first, and a pass that hangs does not hold the stop.

The pass runs in a worker thread that cancelling the loop's task never stops. A pass
that ran on past kopf's cleanup would queue its Events as the process exits, and the
operator would die of SIGABRT (see ``KubeApi.close`` and the live test in
tests/integration/test_operator_cli_process.py).
"""

from __future__ import annotations

import asyncio
import threading
import time

import pytest
from armnet_operator.controller import Controller
from armnet_operator.errors import TransientError
from armnet_operator.metrics import Metrics
from armnet_operator.settings import load_settings

pytestmark = pytest.mark.unit


def a_controller() -> Controller:
    settings = load_settings({"reconcile_period": 0.01, "metrics_port": 0}, environ={})
    return Controller(settings, api=None, metrics=Metrics())  # type: ignore[arg-type]


def test_a_stop_waits_for_the_pass_in_flight_and_starts_no_other() -> None:
    controller = a_controller()
    passes: list[tuple[float, float]] = []
    started = threading.Event()

    def reconcile() -> None:
        begin = time.monotonic()
        started.set()
        time.sleep(0.3)
        passes.append((begin, time.monotonic()))

    controller.reconcile = reconcile  # type: ignore[method-assign]

    async def run() -> float:
        controller.start()
        while not started.is_set():
            await asyncio.sleep(0.005)
        await controller.stop()
        stopped = time.monotonic()
        await asyncio.sleep(0.1)  # a pass the loop started after the stop would show here
        return stopped

    stopped = asyncio.run(asyncio.wait_for(run(), 10))
    assert len(passes) == 1, passes
    assert passes[0][1] <= stopped  # ended before stop() returned, not after
    assert not controller.dead


def stop_during_a_hanging_pass(*, then_fail: bool) -> tuple[Controller, float, BaseException | None]:
    """Stop (0.1 s grace) while a pass hangs; then let the pass end, raising as on the closed API if asked.

    Returns the controller, how long the stop took, and what the pass's task ended with.
    """
    controller = a_controller()
    release = threading.Event()
    started = threading.Event()

    def reconcile() -> None:
        started.set()
        release.wait(10)
        if then_fail:
            raise TransientError("the operator is stopping; request not sent")

    controller.reconcile = reconcile  # type: ignore[method-assign]

    async def run() -> tuple[float, BaseException | None]:
        controller.start()
        while not started.is_set():
            await asyncio.sleep(0.005)
        begin = time.monotonic()
        await controller.stop(grace=0.1)
        took = time.monotonic() - begin
        release.set()
        running = controller._pass
        assert running is not None
        await asyncio.wait({running}, timeout=5)
        return took, running.exception()

    took, ended_with = asyncio.run(asyncio.wait_for(run(), 10))
    return controller, took, ended_with


def test_a_pass_that_outlasts_the_grace_does_not_hold_the_stop() -> None:
    controller, took, _ = stop_during_a_hanging_pass(then_fail=False)
    assert took < 1.0
    assert not controller.dead


def test_a_pass_that_outlasts_the_grace_and_then_fails_on_the_closed_api_ends_quietly() -> None:
    """kopf re-raises the exception of every task it finds done when it ends: the exit was a crash."""
    controller, _, ended_with = stop_during_a_hanging_pass(then_fail=True)
    assert ended_with is None
    assert not controller.dead

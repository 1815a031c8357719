"""A SIGTERM while no kopf run owns the signals is recorded, and stops a run that is starting.

Real signals to this process; the handlers in place before each test are put back after it.
"""

from __future__ import annotations

import asyncio
import os
import signal
from collections.abc import Iterator

import pytest
from armnet_operator.termination import Termination

pytestmark = pytest.mark.unit


@pytest.fixture(autouse=True)
def _restore_handlers() -> Iterator[None]:
    saved = {signum: signal.getsignal(signum) for signum in (signal.SIGTERM, signal.SIGINT)}
    yield
    for signum, handler in saved.items():
        signal.signal(signum, handler)


def test_a_sigterm_between_runs_is_recorded_and_does_not_kill_the_process() -> None:
    termination = Termination().install()

    os.kill(os.getpid(), signal.SIGTERM)

    assert termination.requested.wait(5)


def test_a_sigterm_while_a_run_starts_sets_that_runs_stop_flag() -> None:
    termination = Termination().install()

    async def starting_run() -> bool:
        stop = termination.stop_flag = asyncio.Event()
        os.kill(os.getpid(), signal.SIGTERM)  # before kopf would have put its own handlers in
        await asyncio.wait_for(stop.wait(), 5)
        return stop.is_set()

    assert asyncio.run(starting_run())
    assert termination.requested.is_set()


def test_install_again_after_a_loop_put_the_default_back() -> None:
    termination = Termination().install()

    async def a_run_with_its_own_handler() -> None:
        loop = asyncio.get_running_loop()
        loop.add_signal_handler(signal.SIGTERM, lambda: None)  # as kopf does
        loop.remove_signal_handler(signal.SIGTERM)  # as closing its loop does: SIG_DFL again

    asyncio.run(a_run_with_its_own_handler())
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL
    termination.install()
    os.kill(os.getpid(), signal.SIGTERM)

    assert termination.requested.wait(5)

"""The pty server answers like hardware with its own CPU: its thread is scheduled first."""

from __future__ import annotations

import os
import time

import pytest
from armnet_sim.pty_server import PtyServer

pytestmark = pytest.mark.unit


def serving_thread_id(server: PtyServer) -> int:
    thread = server._thread  # noqa: SLF001 - the scheduling policy is a property of this one thread
    assert thread is not None and thread.native_id is not None
    return thread.native_id


@pytest.mark.skipif(os.geteuid() != 0, reason="real-time scheduling needs CAP_SYS_NICE (the test bed runs as root)")
def test_the_serving_thread_runs_real_time_when_permitted_and_still_echoes() -> None:
    server = PtyServer(lambda data, _now: data.upper(), name="pty-test")
    server.start()
    try:
        port = os.open(server.port, os.O_RDWR | os.O_NOCTTY)
        try:
            os.write(port, b"ping")
            deadline, reply = time.monotonic() + 5, b""
            while len(reply) < 4 and time.monotonic() < deadline:
                reply += os.read(port, 4)
            assert reply == b"PING"
            # Asked once the thread has answered: it sets its policy before its first select.
            assert os.sched_getscheduler(serving_thread_id(server)) == os.SCHED_FIFO
        finally:
            os.close(port)
    finally:
        server.stop()

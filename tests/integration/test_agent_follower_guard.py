"""The agent's follower guard on a real nats-server: beats keep a job alive, silence cancels it once."""

from __future__ import annotations

import asyncio
import threading
import time
import uuid

import nats
import pytest
from armnet_node.follower import FollowerGuard, guard_follower
from armnet_node.publish import NoLink
from armnet_node.streams import NatsLink

pytestmark = [pytest.mark.integration, pytest.mark.timeout(60)]


def beat(url: str, subject: str, times: int, every_s: float) -> None:
    async def run() -> None:
        nc = await nats.connect(url)
        for _ in range(times):
            await nc.publish(subject, b'{"at": "now", "client": "test"}')
            await nc.flush()
            await asyncio.sleep(every_s)
        await nc.close()

    asyncio.run(run())


def guard(link: NatsLink, window_s: float) -> tuple[FollowerGuard, list[str], threading.Event]:
    lost: list[str] = []
    fired = threading.Event()

    def on_lost(message: str) -> None:
        lost.append(message)
        fired.set()

    g = FollowerGuard(link, "team-a", uuid.uuid4().hex, window_s, on_lost, check_every_s=0.05).start()
    assert g._subscription.wait_active(10)
    return g, lost, fired


def test_a_beating_follower_keeps_the_job_alive_past_the_window(link: NatsLink, nats_server: str) -> None:
    g, lost, _ = guard(link, window_s=0.6)
    try:
        beat(nats_server, g.subject, times=12, every_s=0.2)  # 2.4 s, four windows
        assert lost == []
        deadline = time.monotonic() + 5  # the last beat is counted on the link's thread, a moment later
        while g.clock.beats < 12 and time.monotonic() < deadline:
            time.sleep(0.02)
        assert g.clock.beats == 12
    finally:
        g.close()


def test_a_silent_follower_cancels_the_job_once_with_the_reason(link: NatsLink, nats_server: str) -> None:
    g, lost, fired = guard(link, window_s=0.6)
    try:
        beat(nats_server, g.subject, times=2, every_s=0.1)
        assert fired.wait(5)
        time.sleep(0.3)
        assert len(lost) == 1
        assert "sent no heartbeat" in lost[0]
    finally:
        g.close()


def test_beats_of_another_job_do_not_keep_this_one_alive(link: NatsLink, nats_server: str) -> None:
    g, lost, fired = guard(link, window_s=0.6)
    try:
        beat(nats_server, f"clients.team-a.{uuid.uuid4().hex}.heartbeat", times=6, every_s=0.2)
        assert fired.wait(5) and lost
    finally:
        g.close()


def test_an_agent_without_nats_does_not_watch_a_followed_job() -> None:
    assert guard_follower(NoLink(), "team-a", "uid", 10.0, lambda m: None) is None


def test_a_job_without_a_declared_follower_is_not_watched(link: NatsLink) -> None:
    assert guard_follower(link, "team-a", "uid", None, lambda m: None) is None

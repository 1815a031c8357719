"""A client following a non-detached job sends heartbeats on the real NATS while it follows, and only then.

The agent's enforcement (cancel when beats stop) is not built yet; this checks
the client's half: beats on ``clients.<ns>.<jobId>.heartbeat`` during the
follow, none after it, none for a detached job.
"""

from __future__ import annotations

import asyncio
import json
import threading
import time
from typing import Any

import nats
import pytest
from armnet_core.models import JobSpec

from tests.integration.client_bed import Publisher, Tenant, stdout_lines, terminal

pytestmark = pytest.mark.integration


class Listener:
    """Counts heartbeats on one subject from a thread of its own."""

    def __init__(self, url: str, subject: str) -> None:
        self.url, self.subject = url, subject
        self.beats: list[tuple[float, dict[str, Any]]] = []
        self._ready = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=lambda: asyncio.run(self._run()), daemon=True)

    async def _run(self) -> None:
        nc = await nats.connect(self.url)

        async def on_msg(msg: Any) -> None:
            self.beats.append((time.monotonic(), json.loads(msg.data)))

        await nc.subscribe(self.subject, cb=on_msg)
        await nc.flush()
        self._ready.set()
        while not self._stop.is_set():
            await asyncio.sleep(0.05)
        await nc.close()

    def __enter__(self) -> Listener:
        self._thread.start()
        assert self._ready.wait(10)
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(10)


Beats = list[tuple[float, dict[str, Any]]]


def follow_for(
    tenant: Tenant, nats_server: str, name: str, detach: bool, seconds: float
) -> tuple[str, float, Beats]:
    client = tenant.client()
    client.nats_url = nats_server
    client.heartbeat_interval_s = 0.2
    client.submit(JobSpec(image="localhost/pick:dev", embodiment="test/beats", detach=detach), name=name)
    uid = client.read(name).metadata.uid
    assert uid
    publisher = Publisher(nats_server, tenant.namespace, uid)
    publisher.publish(stdout_lines(1, 2))
    listener = Listener(nats_server, f"clients.{tenant.namespace}.{uid}.heartbeat")
    with listener:
        timer = threading.Timer(seconds, lambda: publisher.publish(terminal()))
        timer.start()
        assert [x.text for x in client.logs(name)][-1] == "status: succeeded"
        ended = time.monotonic()
        timer.join()
        time.sleep(1.2)  # beats every 0.2 s would go on: five or more would arrive after the slack below
    return uid, ended, listener.beats


def test_a_non_detached_jobs_follower_beats_while_it_follows_and_stops_after(
    k8s: Any, namespace: str, nats_server: str
) -> None:
    uid, ended, beats = follow_for(Tenant(k8s, namespace), nats_server, "kept", False, 1.5)

    assert len(beats) >= 3
    assert all(at <= ended + 0.5 for at, _ in beats)  # one sent at the end may arrive late on a loaded host
    assert set(beats[0][1]) == {"at", "client"}


def test_a_detached_jobs_follower_sends_no_heartbeats(k8s: Any, namespace: str, nats_server: str) -> None:
    _, _, beats = follow_for(Tenant(k8s, namespace), nats_server, "free", True, 0.8)

    assert beats == []

"""``armnet teleop --leader sim`` in a real terminal (a pty): actions at the rate, keys as events, Esc ends it.

The process runs like a user runs it (``python -m armnet_client teleop``) as a
tenant; the test subscribes to the job's teleop subjects on the real nats-server
as the agent's bridge will. Moving a follower needs the agent (later).
"""

from __future__ import annotations

import asyncio
import json
import os
import pty
import subprocess
import sys
import time
from typing import Any

import nats
import pytest
from armnet_core.models import JobSpec

from tests.integration.client_bed import Tenant

pytestmark = pytest.mark.integration


async def collect(url: str, subject: str, keys: list[bytes], master: int, proc: Any) -> list[tuple[str, Any]]:
    nc = await nats.connect(url)
    got: list[tuple[str, Any]] = []

    async def on_msg(msg: Any) -> None:
        got.append((msg.subject.rsplit(".", 1)[-1], json.loads(msg.data)))

    await nc.subscribe(subject, cb=on_msg)
    deadline = time.monotonic() + 30
    while sum(1 for kind, _ in got if kind == "action") < 5 and time.monotonic() < deadline:
        await asyncio.sleep(0.05)
    for key in keys:
        os.write(master, key)
        await asyncio.sleep(0.3)
    while proc.poll() is None and time.monotonic() < deadline:
        await asyncio.sleep(0.05)
    await nc.flush()
    await nc.close()
    return got


def test_teleop_publishes_sampled_actions_and_key_events_then_esc_ends_it(
    k8s: Any, namespace: str, nats_server: str
) -> None:
    tenant = Tenant(k8s, namespace)
    client = tenant.client()
    client.submit(JobSpec(image="localhost/pick:dev", embodiment="test/teleop"), name="driven")
    uid = client.read("driven").metadata.uid
    master, slave = pty.openpty()
    proc = subprocess.Popen(
        [sys.executable, "-m", "armnet_client", "teleop", "driven", "--leader", "sim", "--rate", "20",
         "--kubeconfig", tenant.kubeconfig, "-n", namespace, "--nats-url", nats_server],
        stdin=slave, stdout=slave, stderr=slave, env={**os.environ}, close_fds=True)
    os.close(slave)
    try:
        got = asyncio.run(collect(nats_server, f"teleop.{namespace}.{uid}.>",
                                  [b"\x1b[C", b"\x1b[D", b"\x1b"], master, proc))
        assert proc.wait(timeout=10) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
        os.close(master)

    actions = [body["action"] for kind, body in got if kind == "action"]
    events = [body["event"] for kind, body in got if kind == "event"]
    assert events == ["next_episode", "rerecord_episode", "stop_recording"]
    assert len(actions) >= 5
    assert set(actions[0]) == {"shoulder_pan.pos", "shoulder_lift.pos", "elbow_flex.pos",
                               "wrist_flex.pos", "wrist_roll.pos", "gripper.pos"}
    assert len({a["shoulder_pan.pos"] for a in actions}) > 1

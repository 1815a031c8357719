"""``armnet teleop --leader sim`` in a real terminal (a pty): actions at the rate, keys as events, Esc ends it,
and the follower's state shown as the job's Rerun packets report it.

The process runs like a user runs it (``python -m armnet_client teleop``) as a
tenant; the test subscribes to the job's teleop subjects on the real nats-server
as the agent's bridge does, and publishes the job's Rerun packets into JetStream
as the agent does. Moving a real follower: e2e/test_client_jobs.py.
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
from armnet_runtime.rerun import Entry, Packet, encode_packet

from tests.integration.client_bed import Publisher, Tenant
from tests.support.pty_screen import Screen

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
        assert proc.wait(timeout=60) == 0  # exit after Esc; a loaded host can stall an exit for seconds
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


def test_teleop_shows_the_followers_state_from_the_jobs_rerun_packets(
    k8s: Any, namespace: str, nats_server: str
) -> None:
    tenant = Tenant(k8s, namespace)
    client = tenant.client()
    client.submit(JobSpec(image="localhost/pick:dev", embodiment="test/teleop"), name="watched")
    uid = client.read("watched").metadata.uid
    assert uid
    master, slave = pty.openpty()
    proc = subprocess.Popen(
        [sys.executable, "-m", "armnet_client", "teleop", "watched", "--leader", "sim", "--rate", "20",
         "--kubeconfig", tenant.kubeconfig, "-n", namespace, "--nats-url", nats_server],
        stdin=slave, stdout=slave, stderr=slave, env={**os.environ}, close_fds=True)
    os.close(slave)
    screen = Screen(master)
    try:
        screen.wait_for(lambda text: b"follower: no state yet" in text, "the waiting follower line")
        Publisher(nats_server, namespace, uid).publish([("rerun", i + 1, encode_packet(Packet(uid, i, i, 0, (
            Entry("observation.shoulder_pan.pos", scalar=12.5 + i),
            Entry("action.shoulder_pan.pos", scalar=99.0),
            Entry("observation.gripper.pos", scalar=40.0),
        )))) for i in range(2)])

        screen.wait_for(lambda text: b"shoulder_pan 13.5  gripper 40.0" in text, "the follower's last state")
        os.write(master, b"\x1b")
        assert proc.wait(timeout=60) == 0  # exit after Esc; a loaded host can stall an exit for seconds
    finally:
        if proc.poll() is None:
            proc.kill()
        os.close(master)

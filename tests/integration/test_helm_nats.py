"""The bundled NATS's users keep tenants to their own namespace's subjects.

The chart's rendered nats.conf runs in a real nats-server; the test changes only where
it listens (127.0.0.1, a free port, no monitoring port) and its store directory.
Clients are the real nats-py. Subjects: docs/streams.md.
"""

from __future__ import annotations

import json
import os
import subprocess
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import nats
import pytest
from armnet_testbed.procs import require_tool

from tests.support import helm_nats
from tests.support.helm import find, render
from tests.support.helm_nats import ENV, Server, connect, run, settle, violated

pytestmark = pytest.mark.integration

#: The chart's nats.conf (auth on) in a real nats-server (a fixture: bound here by name).
server = helm_nats.server


Session = Callable[[Any, list[str]], Awaitable[None]]


def test_tenant_cannot_subscribe_to_another_namespaces_logs(server: Server) -> None:
    async def body(server: Server) -> None:
        errors: list[str] = []
        tenant = await connect(server, "tenant-team-a", errors)
        agent = await connect(server, "agent")
        got: list[str] = []

        async def on_msg(msg: Any) -> None:
            got.append(msg.subject)

        await tenant.subscribe("logs.team-b.>", cb=on_msg)
        await tenant.subscribe("logs.>", cb=on_msg)
        await settle(tenant)
        await agent.publish("logs.team-b.job-2.stdout", b"theirs")
        await settle(agent, tenant)
        await tenant.close()
        await agent.close()

        assert got == []
        assert violated(errors, 'Subscription to "logs.team-b.>"'), errors
        assert violated(errors, 'Subscription to "logs.>"'), errors

    run(server, body)


def test_tenant_receives_its_own_namespaces_logs(server: Server) -> None:
    async def body(server: Server) -> None:
        tenant = await connect(server, "tenant-team-a")
        agent = await connect(server, "agent")
        sub = await tenant.subscribe("logs.team-a.>")
        await settle(tenant)
        await agent.publish("logs.team-a.job-1.stdout", b"mine")
        msg = await sub.next_msg(timeout=5)
        await tenant.close()
        await agent.close()

        assert (msg.subject, msg.data) == ("logs.team-a.job-1.stdout", b"mine")

    run(server, body)


def test_tenant_cannot_send_teleop_input_to_another_namespaces_job(server: Server) -> None:
    async def body(server: Server) -> None:
        errors: list[str] = []
        tenant = await connect(server, "tenant-team-a", errors)
        agent = await connect(server, "agent")
        sub = await agent.subscribe("teleop.>")
        await settle(agent)
        await tenant.publish("teleop.team-b.job-2.action", b'{"action": {"shoulder_pan": 90}}')
        await tenant.publish("teleop.team-a.job-1.event", b'{"event": "next_episode"}')
        msg = await sub.next_msg(timeout=5)
        await settle(tenant, agent)
        await tenant.close()
        await agent.close()

        assert msg.subject == "teleop.team-a.job-1.event"
        assert sub.pending_msgs == 0
        assert violated(errors, 'Publish to "teleop.team-b.job-2.action"'), errors

    run(server, body)


def test_tenant_cannot_confirm_a_reset_on_a_cell(server: Server) -> None:
    async def body(server: Server) -> None:
        errors: list[str] = []
        tenant = await connect(server, "tenant-team-a", errors)
        await tenant.publish("fms.cell-1.reset.confirm", b'{"by": "tenant", "request": null}')
        await settle(tenant)
        await tenant.close()

        assert violated(errors, 'Publish to "fms.cell-1.reset.confirm"'), errors

    run(server, body)


def test_tenant_can_neither_hear_nor_forge_a_cells_telemetry(server: Server) -> None:
    async def body(server: Server) -> None:
        errors: list[str] = []
        tenant = await connect(server, "tenant-team-a", errors)
        await tenant.subscribe("telemetry.>")
        await tenant.publish("telemetry.cell-1.camera.front", b"\xff\xd8\xff forged")
        await settle(tenant)
        await tenant.close()

        assert violated(errors, 'Subscription to "telemetry.>"'), errors
        assert violated(errors, 'Publish to "telemetry.cell-1.camera.front"'), errors

    run(server, body)


async def create_consumer(client: Any, name: str, filter_in_subject: str, filter_in_config: str,
                          deliver: str) -> dict[str, Any]:
    request = {"stream_name": "ARMNET_LOGS", "config": {
        "name": name, "filter_subject": filter_in_config, "deliver_subject": deliver,
        "ack_policy": "none", "deliver_policy": "all"}}
    reply = await client.request(f"$JS.API.CONSUMER.CREATE.ARMNET_LOGS.{name}.{filter_in_subject}",
                                 json.dumps(request).encode(), timeout=3)
    return json.loads(reply.data)


@pytest.fixture(scope="module")
def stream(server: Server) -> None:
    async def body(server: Server) -> None:
        agent = await connect(server, "agent")
        js = agent.jetstream()
        await js.add_stream(name="ARMNET_LOGS", subjects=["logs.>"])
        await js.publish("logs.team-a.job-1.stdout", b"mine")
        await js.publish("logs.team-b.job-2.stdout", b"theirs")
        await agent.close()

    run(server, body)


def test_tenant_replays_its_own_namespace_from_the_stream(server: Server, stream: None) -> None:
    async def body(server: Server) -> None:
        tenant = await connect(server, "tenant-team-a", inbox_prefix="_INBOX.team-a")
        sub = await tenant.subscribe("_INBOX.team-a.replay")
        created = await create_consumer(tenant, "replay-a", "logs.team-a.>", "logs.team-a.>",
                                        "_INBOX.team-a.replay")
        msg = await sub.next_msg(timeout=5)
        await tenant.close()

        assert "error" not in created, created
        assert (msg.subject, msg.data) == ("logs.team-a.job-1.stdout", b"mine")

    run(server, body)


def test_tenant_cannot_open_a_stream_consumer_on_another_namespace(server: Server, stream: None) -> None:
    async def body(server: Server) -> None:
        errors: list[str] = []
        tenant = await connect(server, "tenant-team-a", errors, inbox_prefix="_INBOX.team-a")
        with pytest.raises(nats.errors.TimeoutError):
            await create_consumer(tenant, "peek-b", "logs.team-b.>", "logs.team-b.>", "_INBOX.team-a.peek")
        await tenant.close()

        assert violated(errors, "Publish to \"$JS.API.CONSUMER.CREATE.ARMNET_LOGS.peek-b"), errors

    run(server, body)


def test_tenant_cannot_smuggle_another_filter_past_the_subject_check(server: Server, stream: None) -> None:
    async def body(server: Server) -> None:
        tenant = await connect(server, "tenant-team-a", inbox_prefix="_INBOX.team-a")
        created = await create_consumer(tenant, "smuggle", "logs.team-a.>", "logs.team-b.>",
                                        "_INBOX.team-a.smuggle")
        await tenant.close()

        assert "error" in created, created

    run(server, body)


def test_tenant_cannot_read_replies_on_another_tenants_inbox(server: Server) -> None:
    async def body(server: Server) -> None:
        errors: list[str] = []
        tenant = await connect(server, "tenant-team-a", errors, inbox_prefix="_INBOX.team-a")
        await tenant.subscribe("_INBOX.team-b.>")
        await settle(tenant)
        await tenant.close()

        assert violated(errors, 'Subscription to "_INBOX.team-b.>"'), errors

    run(server, body)


def test_rendered_config_passes_nats_server_config_check(tmp_path: Path) -> None:
    values = {"nats": {"deploy": {"enabled": True, "auth": {
        "enabled": True, "existingSecret": "nats-users", "tenants": ["team-a", "team-b"]}}}}
    config = find(render(values=values), "ConfigMap", "-nats")["data"]["nats.conf"]
    (tmp_path / "nats.conf").write_text(config.replace("/data/jetstream", str(tmp_path / "js")))
    result = subprocess.run([require_tool("nats-server"), "-t", "-c", str(tmp_path / "nats.conf")],
                            env={**os.environ, **ENV}, capture_output=True, text=True, timeout=30, check=False)

    assert result.returncode == 0, result.stderr

"""The chart's bundled NATS (auth on) in a real nats-server, and nats-py clients to test its users' permissions.

:func:`server` is a module-scoped pytest fixture: a test module that wants it binds it
by name (``server = helm_nats.server``), and gets its own nats-server. The chart's
rendered nats.conf runs with only where it listens (127.0.0.1, a free port, no
monitoring port) and its store directory changed. The users (agent, fms, a tenant
per namespace team-a and team-b) log in with :data:`PASSWORDS`; :func:`violated`
reads the permission violations the server reports. Subjects: docs/streams.md.
"""

from __future__ import annotations

import asyncio
import os
import re
import socket
from collections.abc import Awaitable, Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import nats
import pytest
from armnet_testbed.procs import ManagedProcess, free_port, require_tool, wait_until

from tests.support.helm import find, render

PASSWORDS = {"agent": "agent-pw", "fms": "fms-pw", "tenant-team-a": "a-pw", "tenant-team-b": "b-pw"}
#: The passwords as the chart's nats.conf reads them (from the users Secret, in the pod's environment).
ENV = {"NATS_AGENT_PASSWORD": "agent-pw", "NATS_FMS_PASSWORD": "fms-pw",
       "NATS_TENANT_TEAM_A_PASSWORD": "a-pw", "NATS_TENANT_TEAM_B_PASSWORD": "b-pw"}


@dataclass(frozen=True)
class Server:
    url: str


@contextmanager
def chart_nats_server(workdir: Path) -> Iterator[int]:
    """A nats-server running the chart's rendered nats.conf (tenants team-a and team-b) in ``workdir``; its port."""
    values = {"nats": {"deploy": {"enabled": True, "auth": {
        "enabled": True, "existingSecret": "nats-users", "tenants": ["team-a", "team-b"]}}}}
    config = find(render(values=values), "ConfigMap", "-nats")["data"]["nats.conf"]
    port = free_port()
    config = re.sub(r"(?m)^port: 4222$", f"host: 127.0.0.1\nport: {port}", config)
    config = re.sub(r"(?m)^http_port: .*$", "", config)
    config = config.replace("/data/jetstream", str(workdir / "jetstream"))
    (workdir / "nats.conf").write_text(config)
    proc = ManagedProcess("nats-server", [require_tool("nats-server"), "-c", str(workdir / "nats.conf")],
                          workdir / "nats.log", env={**os.environ, **ENV})

    def accepts() -> bool:
        with socket.create_connection(("127.0.0.1", port), timeout=1) as sock:
            return sock.recv(4).startswith(b"INFO")

    try:
        wait_until(accepts, timeout=20, what="nats-server with the chart's config", alive=proc.ensure_running)
        yield port
    finally:
        proc.stop()


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    with chart_nats_server(tmp_path_factory.mktemp("helm-nats")) as port:
        yield Server(url=f"nats://127.0.0.1:{port}")


def run(server: Server, body: Callable[..., Awaitable[None]]) -> None:
    asyncio.run(asyncio.wait_for(body(server), timeout=30))


async def connect(server: Server, user: str, errors: list[str] | None = None,
                  inbox_prefix: str | None = None) -> Any:
    async def on_error(error: Exception) -> None:
        if errors is not None:
            errors.append(str(error))

    options: dict[str, Any] = {"inbox_prefix": inbox_prefix} if inbox_prefix else {}
    return await nats.connect(server.url, user=user, password=PASSWORDS[user], error_cb=on_error,
                              allow_reconnect=False, **options)


def violated(errors: list[str], what: str) -> bool:
    """Whether the server reported a permissions violation for ``what`` (nats-py lower-cases it)."""
    return any("permissions violation" in e.lower() and what.lower() in e.lower() for e in errors)


async def settle(*clients: Any) -> None:
    """Round trips so the server has handled (and answered) everything sent before."""
    for client in clients:
        await client.flush(timeout=5)
    await asyncio.sleep(0.2)

"""Shared hands of the client's integration tests: a granted tenant, and the agent's log publishing.

Payloads follow docs/streams.md (the agent's streams): output lines as printed,
status as JSON ``{"phase", "detail", "at"}``, message ids ``<jobId>:<kind>:<seq>``.
"""

from __future__ import annotations

import asyncio
import json
import threading
import time
import uuid
from typing import Any

import nats
import yaml
from armnet_cli.main import main as armnet
from armnet_client import Client
from armnet_core.api import CELLQUOTAS, CELLS, GROUP, ROBOTJOBS
from nats.js.api import StreamConfig

STREAM = "ARMNET_LOGS"


def grant_tenant(k8s: Any, namespace: str, user: str) -> None:
    """What a cluster admin gives a tenant (the chart's roles): RobotJobs in its namespace, read-only Cells and CellQuotas."""
    k8s.kubectl("apply", "-f", "-", input=yaml.safe_dump_all([
        {"apiVersion": "rbac.authorization.k8s.io/v1", "kind": "Role",
         "metadata": {"name": "armnet-tenant", "namespace": namespace},
         "rules": [{"apiGroups": [GROUP], "resources": ["robotjobs"],
                    "verbs": ["get", "list", "watch", "create", "patch", "delete"]}]},
        {"apiVersion": "rbac.authorization.k8s.io/v1", "kind": "RoleBinding",
         "metadata": {"name": f"armnet-tenant-{user}", "namespace": namespace},
         "roleRef": {"apiGroup": "rbac.authorization.k8s.io", "kind": "Role", "name": "armnet-tenant"},
         "subjects": [{"kind": "User", "name": user, "apiGroup": "rbac.authorization.k8s.io"}]},
        # Not the chart's name: a Helm test of the same session installs the chart's own
        # ClusterRole, and Helm refuses to take over one it did not make.
        {"apiVersion": "rbac.authorization.k8s.io/v1", "kind": "ClusterRole",
         "metadata": {"name": "armnet-test-cell-reader"},
         "rules": [{"apiGroups": [GROUP], "resources": ["cells", "cellquotas"], "verbs": ["get", "list", "watch"]}]},
        {"apiVersion": "rbac.authorization.k8s.io/v1", "kind": "ClusterRoleBinding",
         "metadata": {"name": f"armnet-test-cell-reader-{user}"},
         "roleRef": {"apiGroup": "rbac.authorization.k8s.io", "kind": "ClusterRole",
                     "name": "armnet-test-cell-reader"},
         "subjects": [{"kind": "User", "name": user, "apiGroup": "rbac.authorization.k8s.io"}]},
    ]))
    wait_authorized(k8s, user, ("create", f"{ROBOTJOBS}.{GROUP}", "-n", namespace), ("list", f"{CELLS}.{GROUP}"), ("list", f"{CELLQUOTAS}.{GROUP}"))


def wait_authorized(k8s: Any, user: str, *checks: tuple[str, ...], timeout_s: float = 20.0) -> None:
    """Until the apiserver's authorizer allows each check as ``user``: RBAC learns new bindings from an
    informer, so a request made the moment a binding is created can still be refused."""
    deadline = time.monotonic() + timeout_s
    for check in checks:
        while k8s.kubectl("auth", "can-i", "--as", user, *check, check=False).stdout.strip() != "yes":
            if time.monotonic() > deadline:
                raise AssertionError(f"{user} is still not allowed to {' '.join(check)} after {timeout_s:.0f} s")
            time.sleep(0.05)


class Tenant:
    def __init__(self, k8s: Any, namespace: str) -> None:
        self.name = f"tenant-{uuid.uuid4().hex[:6]}"
        self.namespace = namespace
        self.user = k8s.user(self.name)
        grant_tenant(k8s, namespace, self.name)
        self.kubeconfig = str(self.user.kubeconfig)

    def client(self, namespace: str | None = None) -> Client:
        return Client(kubeconfig=self.kubeconfig, namespace=namespace or self.namespace, env={})

    def cli(self, *args: str) -> int:
        return armnet([*args, "--kubeconfig", self.kubeconfig, "-n", self.namespace])


async def _ensure_stream(js: Any) -> None:
    config = StreamConfig(name=STREAM, subjects=["logs.>"], duplicate_window=600.0)
    try:
        await js.add_stream(config)
    except Exception:  # noqa: BLE001 - already there from another test of the session
        await js.update_stream(config)


class Publisher:
    """The agent's side of one job: numbered lines per kind, retried until acknowledged."""

    def __init__(self, url: str, namespace: str, job_id: str) -> None:
        self.url, self.ns, self.job = url, namespace, job_id

    async def _publish_all(self, items: list[tuple[str, int, bytes]]) -> None:
        nc = await nats.connect(self.url, max_reconnect_attempts=-1, reconnect_time_wait=0.1,
                                error_cb=_quiet)
        js = nc.jetstream()
        await _ensure_stream(js)
        for kind, seq, payload in items:
            subject = f"logs.{self.ns}.{self.job}.{kind}"
            while True:
                try:
                    await js.publish(subject, payload, stream=STREAM, timeout=2,
                                     headers={"Nats-Msg-Id": f"{self.job}:{kind}:{seq}"})
                    break
                except Exception:  # noqa: BLE001 - server restarting: retry, JetStream dedups
                    await asyncio.sleep(0.1)
        await nc.close()

    def publish(self, items: list[tuple[str, int, bytes]]) -> None:
        asyncio.run(self._publish_all(items))

    def in_thread(self, items: list[tuple[str, int, bytes]]) -> threading.Thread:
        thread = threading.Thread(target=self.publish, args=(items,), daemon=True)
        thread.start()
        return thread


async def _quiet(_exc: Exception) -> None:
    return None


def stdout_lines(first: int, last: int) -> list[tuple[str, int, bytes]]:
    return [("stdout", i, f"line {i}".encode()) for i in range(first, last + 1)]


def terminal(phase: str = "succeeded") -> list[tuple[str, int, bytes]]:
    return [("status", 1, json.dumps({"phase": phase, "detail": {}, "at": "2026-11-24T10:00:00Z"}).encode())]



"""A Cell says whether its agent's NATS link can carry the cell operator's inputs.

The real API server and a real nats-server: a cell worker heartbeats its Cell with
``StreamsConnected`` beside its health conditions, and the FMS lists it with the
cell's other false conditions. Without the link the FMS's Confirm reset and
Success/Fail never reach the job, so the Cell must say so, not look "live".
"""

from __future__ import annotations

import contextlib
import shutil
import tempfile
import time
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from armnet_core.api import CELLS, GROUP, VERSION
from armnet_fms.view import build_row
from armnet_node.kube import AgentKube
from armnet_node.metrics import AgentMetrics
from armnet_node.model import parse_cell
from armnet_node.plan import HostPaths
from armnet_node.publish import Link, NoLink
from armnet_node.runner import RunnerDeps
from armnet_node.streams import NatsLink, StreamSettings
from armnet_node.telemetry import TelemetrySettings
from armnet_node.worker import CellWorker, WorkerSettings
from armnet_testbed.procs import free_port
from kubernetes import client

from tests.support.fms_objects import a_cell, apply, get
from tests.support.sim_connector import connected_link

pytestmark = pytest.mark.integration


@contextlib.contextmanager
def heartbeating_cell(k8s: Any, link: Link) -> Iterator[str]:
    """A simulated Cell with its agent's worker running on ``link``; the Cell's name."""
    name = f"streams-{uuid.uuid4().hex[:8]}"
    cell = parse_cell(apply(k8s, a_cell(name)))
    state_dir = Path(tempfile.mkdtemp(prefix="ant-", dir="/tmp"))
    deps = RunnerDeps(kube=AgentKube(k8s.api_client()), launcher=None,  # type: ignore[arg-type]  # no job here
                      paths=HostPaths(state_dir), metrics=AgentMetrics(), link=link, uploads=None)
    no_telemetry = TelemetrySettings(servo_hz=0, frame_fps=0)
    worker = CellWorker(cell, deps, WorkerSettings(heartbeat_period=1, telemetry=no_telemetry)).start()
    try:
        yield name
    finally:
        worker.stop()
        shutil.rmtree(state_dir, ignore_errors=True)
        client.CustomObjectsApi(k8s.api_client()).delete_cluster_custom_object(GROUP, VERSION, CELLS, name)


def streams_condition(k8s: Any, name: str, status: str, timeout: float = 60) -> dict[str, Any]:
    """The Cell's StreamsConnected condition, once it has ``status``."""
    deadline = time.monotonic() + timeout
    last: dict[str, Any] | None = None
    while time.monotonic() < deadline:
        conditions = (get(k8s, "cell", name).get("status") or {}).get("conditions") or []
        last = next((c for c in conditions if c["type"] == "StreamsConnected"), None)
        if last is not None and last["status"] == status:
            return last
        time.sleep(0.2)
    raise AssertionError(f"StreamsConnected={status} never appeared on {name}; last: {last!r}")


def test_an_agent_without_nats_marks_its_cells_and_the_fms_lists_why(k8s: Any) -> None:
    with heartbeating_cell(k8s, NoLink()) as name:
        condition = streams_condition(k8s, name, "False")
        assert condition["reason"] == "NatsNotConfigured"
        assert "Confirm reset" in condition["message"] and "NATS_URL" in condition["message"]
        body = get(k8s, "cell", name)
    agent = next(c for c in body["status"]["conditions"] if c["type"] == "AgentConnected")
    assert agent["status"] == "True", "the agent itself is alive: only its streams are missing"
    row = build_row(body, {}, None, time.time())
    assert [c.reason for c in row.false_conditions if c.type == "StreamsConnected"] == ["NatsNotConfigured"]


def test_an_agent_with_a_connected_link_marks_its_cells_connected(k8s: Any, nats_server: str) -> None:
    with connected_link(nats_server) as link, heartbeating_cell(k8s, link) as name:
        assert streams_condition(k8s, name, "True")["reason"] == "Connected"


def test_an_agent_whose_nats_does_not_answer_names_the_server_it_tries(k8s: Any, tmp_path: Path) -> None:
    port = free_port()  # a loopback port nothing listens on (claimed: no other service is started on it)
    link = NatsLink(StreamSettings(url=f"nats://agent:pw@127.0.0.1:{port}", spool_dir=tmp_path)).start()
    try:
        with heartbeating_cell(k8s, link) as name:
            condition = streams_condition(k8s, name, "False")
            assert condition["reason"] == "NatsUnreachable"
            assert f"127.0.0.1:{port}" in condition["message"] and "pw" not in condition["message"]
    finally:
        link.stop(timeout_s=1)

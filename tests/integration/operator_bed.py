"""The operator's live test bed: the test's hands on a real cluster, and the operator run in-process.

Shared by the operator's integration tests (scheduling, hostile objects, fuzzed
manifests) and the client's tests against a running operator. ``Bed`` plays the
node agent's part: it heartbeats Cells and patches RobotJob status exactly as the
agent does. The ``bed`` and ``operator`` fixtures are in this directory's conftest.py.
"""

from __future__ import annotations

import contextlib
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from datetime import UTC, datetime
from typing import Any

import kopf
import pytest
import yaml
from armnet_core.api import API_VERSION, CELLS, GROUP, ROBOTJOBS, TERMINAL_PHASES, VERSION
from armnet_core.times import kube_time
from armnet_operator.handlers import build_registry
from armnet_operator.settings import load_settings
from kopf.testing import KopfRunner
from kubernetes import client


def stamp() -> str:
    return kube_time(datetime.now(UTC))


class Bed:
    """The test's hands on the cluster: kubectl apply, agent-style status patches, waits."""

    def __init__(self, k8s: Any, namespace: str) -> None:
        self.k8s = k8s
        self.ns = namespace
        self.api = client.CustomObjectsApi(k8s.api_client())
        self.core = client.CoreV1Api(k8s.api_client())
        self.embodiment = f"test/{uuid.uuid4().hex[:8]}"
        self.cells: list[str] = []
        self.alive: set[str] = set()
        self._stop = threading.Event()
        self._beat = threading.Thread(target=self._heartbeat_loop, daemon=True)
        self._beat.start()

    # ---- submitting, as a user would
    def apply(self, doc: dict[str, Any]) -> None:
        self.k8s.kubectl("apply", "-f", "-", input=yaml.safe_dump(doc))

    def cell(self, name: str, task: str | None = None, unschedulable: bool = False, alive: bool = True) -> str:
        name = f"{name}-{self.ns}"
        spec: dict[str, Any] = {"embodiment": self.embodiment, "nodeName": "host-1",
                                "unschedulable": unschedulable}
        if task:
            spec["task"] = task
        self.apply({"apiVersion": API_VERSION, "kind": "Cell", "metadata": {"name": name}, "spec": spec})
        self.cells.append(name)
        if alive:
            self.beat(name)
            self.alive.add(name)
        return name

    def job(self, name: str, embodiment: str | None = None, **spec: Any) -> str:
        body = {"image": "localhost/armnet-test:dev", "embodiment": embodiment or self.embodiment, **spec}
        self.apply({"apiVersion": API_VERSION, "kind": "RobotJob",
                    "metadata": {"name": name, "namespace": self.ns}, "spec": body})
        return name

    # ---- the agent's part
    def beat(self, cell: str) -> None:
        self.api.patch_cluster_custom_object_status(GROUP, VERSION, CELLS, cell, {"status": {
            "lastHeartbeatTime": stamp(),
            "conditions": [{"type": "AgentConnected", "status": "True", "reason": "Heartbeat",
                            "message": "", "lastTransitionTime": stamp()}]}})

    def _heartbeat_loop(self) -> None:
        while not self._stop.wait(0.5):
            for cell in list(self.alive):
                with contextlib.suppress(Exception):
                    self.beat(cell)

    def agent_sets(self, job: str, phase: str, *, precondition: str | None = None, **extra: Any) -> None:
        """Write the job's status as the agent does; ``precondition`` is the resourceVersion the
        write was decided on (the real agent always sends one: a 409 means re-read and decide)."""
        status: dict[str, Any] = {"phase": phase, **extra}
        if phase == "running":
            status["startedAt"] = stamp()
        if phase in TERMINAL_PHASES:
            status["finishedAt"] = stamp()
        body: dict[str, Any] = {"status": status}
        if precondition is not None:
            body["metadata"] = {"resourceVersion": precondition}
        self.api.patch_namespaced_custom_object_status(GROUP, VERSION, self.ns, ROBOTJOBS, job, body)

    # ---- looking
    def get_job(self, name: str) -> dict[str, Any] | None:
        try:
            return self.api.get_namespaced_custom_object(GROUP, VERSION, self.ns, ROBOTJOBS, name)
        except client.ApiException as error:
            if error.status == 404:
                return None
            raise

    def get_cell(self, name: str) -> dict[str, Any]:
        return self.api.get_cluster_custom_object(GROUP, VERSION, CELLS, name)

    def wait(self, what: str, check: Callable[[], Any], timeout: float = 30) -> Any:
        deadline = time.monotonic() + timeout
        last: Any = None
        while time.monotonic() < deadline:
            last = check()
            if last:
                return last
            time.sleep(0.2)
        raise AssertionError(f"timed out after {timeout}s waiting for {what}; last: {last!r}")

    def wait_job(self, name: str, **status: Any) -> dict[str, Any]:
        def check() -> dict[str, Any] | None:
            body = self.get_job(name)
            got = (body or {}).get("status", {})
            return body if all(got.get(k) == v for k, v in status.items()) else None
        return self.wait(f"job {name} with {status}", check)

    def condition(self, body: dict[str, Any], type_: str) -> dict[str, Any]:
        return next(c for c in body["status"]["conditions"] if c["type"] == type_)

    def events(self, name: str) -> list[str]:
        events = self.core.list_namespaced_event(self.ns, field_selector=f"involvedObject.name={name}")
        return [e.reason for e in events.items]

    def close(self) -> None:
        self._stop.set()
        self._beat.join(timeout=5)
        for cell in self.cells:
            self.k8s.kubectl("delete", "cell", cell, "--ignore-not-found", "--wait=false", check=False)


def operator_settings(k8s: Any, namespace: str, **overrides: Any) -> Any:
    values = {
        "namespaces": (namespace,), "kubeconfig": str(k8s.kubeconfig), "metrics_port": 0,
        "lease_namespace": namespace, "lease_duration": 3, "heartbeat_timeout": 3,
        "claim_grace": 2, "lost_grace": 2, "cancel_force_after": 2, "reconcile_period": 0.5,
        "position_refresh": 0, "identity": f"replica-{uuid.uuid4().hex[:6]}",
    }
    values.update(overrides)
    return load_settings(values, environ={})


@contextlib.contextmanager
def running_operator(k8s: Any, namespace: str, monkeypatch: pytest.MonkeyPatch, **overrides: Any) -> Iterator[Any]:
    monkeypatch.setenv("KUBECONFIG", str(k8s.kubeconfig))  # kopf's own login
    settings = operator_settings(k8s, namespace, **overrides)
    registry, controller = build_registry(settings)
    kopf_settings = kopf.OperatorSettings()
    kopf_settings.watching.server_timeout = 10
    args = ["run", "--standalone"]
    for watched in settings.namespaces:
        args += ["--namespace", watched]
    with KopfRunner(args, registry=registry, settings=kopf_settings, timeout=120) as runner:
        yield controller
    assert runner.exception is None, runner.output
    assert runner.exit_code == 0, runner.output
    assert "Traceback" not in runner.output, runner.output

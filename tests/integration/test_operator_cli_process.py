"""`armnet operator` as a real process: it binds a job, serves /metrics, and exits at SIGTERM."""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
import time
import urllib.request
import uuid
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pytest
import yaml
from armnet_core.api import API_VERSION, CELLS, GROUP, ROBOTJOBS, VERSION
from armnet_core.times import kube_time
from armnet_testbed.procs import free_port
from kubernetes import client

from tests.support.processes import stop_process

pytestmark = pytest.mark.integration


def test_the_armnet_operator_command_binds_a_job_exports_metrics_and_exits_0_at_sigterm(
        k8s: Any, namespace: str) -> None:
    port = free_port()
    embodiment = f"test/{uuid.uuid4().hex[:8]}"
    cell = f"cli-{namespace}"
    argv = [sys.executable, "-m", "armnet_cli.main", "operator", "--kubeconfig", str(k8s.kubeconfig),
            "--namespaces", namespace, "--lease-namespace", namespace, "--metrics-port", str(port),
            "--metrics-address", "127.0.0.1", "--reconcile-period", "0.5"]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env={**os.environ, "KUBECONFIG": str(k8s.kubeconfig)})
    try:
        now = kube_time(datetime.now(UTC))
        k8s.kubectl("apply", "-f", "-", input=yaml.safe_dump({
            "apiVersion": "armnet.io/v1alpha1", "kind": "Cell", "metadata": {"name": cell},
            "spec": {"embodiment": embodiment, "nodeName": "host-1"}}))
        k8s.kubectl("patch", "cell", cell, "--subresource=status", "--type=merge",
                    "-p", json.dumps({"status": {"lastHeartbeatTime": now}}))
        k8s.kubectl("apply", "-n", namespace, "-f", "-", input=yaml.safe_dump({
            "apiVersion": "armnet.io/v1alpha1", "kind": "RobotJob", "metadata": {"name": "cli-job"},
            "spec": {"image": "localhost/armnet-test:dev", "embodiment": embodiment}}))
        deadline, beaten = time.monotonic() + 60, time.monotonic()
        phase = None
        while time.monotonic() < deadline and phase != "dispatched":
            time.sleep(0.5)
            if time.monotonic() - beaten > 5:
                # The cell's agent keeps its heartbeat fresh: an operator process slower to start than
                # the heartbeat timeout (Python and kopf imports at load ~12) must find it online.
                beaten = time.monotonic()
                k8s.kubectl("patch", "cell", cell, "--subresource=status", "--type=merge",
                            "-p", json.dumps({"status": {"lastHeartbeatTime": kube_time(datetime.now(UTC))}}))
            out = k8s.kubectl("get", "rj", "cli-job", "-n", namespace, "-o", "jsonpath={.status.phase}").stdout
            phase = out.strip()
            assert proc.poll() is None, proc.stdout.read() if proc.stdout else ""
        assert phase == "dispatched"
        # The pass updates its metrics when it ends, a moment after its writes are visible.
        deadline = time.monotonic() + 10
        while True:
            metrics = urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=5).read().decode()
            if "armnet_binds_total 1.0" in metrics or time.monotonic() > deadline:
                break
            time.sleep(0.2)
        assert "armnet_binds_total 1.0" in metrics
        assert "armnet_operator_leader 1.0" in metrics
        # A Deployment's rollout sends SIGTERM: the operator must end by itself, well inside
        # the pod's grace period (it once hung after its cleanup until SIGKILL: kopf waited
        # for a threading.Event stop flag in an executor thread nothing woke).
        proc.terminate()
        assert proc.wait(timeout=15) == 0
    finally:
        stop_process(proc)
        k8s.kubectl("delete", "cell", cell, "--ignore-not-found", "--wait=false", check=False)


def test_a_sigterm_during_a_binding_pass_lets_the_pass_end_posts_its_events_and_exits_0(
        k8s: Any, namespace: str, tmp_path: Path) -> None:
    """SIGTERM while a pass binds a burst: the process exits 0 and no bound job misses its Bound Event.

    The hazard: if cancelling the loop left the pass running after kopf's cleanup, its Events
    would go to the poster (a daemon thread) as the interpreter exits, and CPython would end
    that thread inside an HTTPS call with an unwind that aborts the process (SIGABRT, -6).
    Without the ordered stop, this burst hits it on every run (the CRD-lifecycle test rarely).
    """
    burst = 40
    embodiment = f"test/{uuid.uuid4().hex[:8]}"
    api = client.CustomObjectsApi(k8s.api_client())
    core = client.CoreV1Api(k8s.api_client())
    cells = [f"sigterm-{i}-{namespace}" for i in range(burst)]
    now = kube_time(datetime.now(UTC))
    log = tmp_path / "operator.log"
    argv = [sys.executable, "-m", "armnet_cli.main", "operator", "--kubeconfig", str(k8s.kubeconfig),
            "--namespaces", namespace, "--lease-namespace", namespace, "--metrics-port", "0",
            "--reconcile-period", "0.5", "--heartbeat-timeout", "300"]
    proc: subprocess.Popen[str] | None = None
    try:
        for cell in cells:
            api.create_cluster_custom_object(GROUP, VERSION, CELLS, {
                "apiVersion": API_VERSION, "kind": "Cell", "metadata": {"name": cell},
                "spec": {"embodiment": embodiment, "nodeName": "host-1"}})
            api.patch_cluster_custom_object_status(GROUP, VERSION, CELLS, cell,
                                                   {"status": {"lastHeartbeatTime": now}})
        with log.open("w") as out:
            proc = subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT, text=True,
                                    env={**os.environ, "KUBECONFIG": str(k8s.kubeconfig)})
        deadline = time.monotonic() + 60
        while "gained leadership" not in log.read_text():
            assert proc.poll() is None and time.monotonic() < deadline, log.read_text()[-3000:]
            time.sleep(0.1)
        for i in range(burst):
            api.create_namespaced_custom_object(GROUP, VERSION, namespace, ROBOTJOBS, {
                "apiVersion": API_VERSION, "kind": "RobotJob", "metadata": {"name": f"burst-{i}"},
                "spec": {"image": "localhost/armnet-test:dev", "embodiment": embodiment}})

        def dispatched() -> set[str]:
            jobs = api.list_namespaced_custom_object(GROUP, VERSION, namespace, ROBOTJOBS)["items"]
            return {j["metadata"]["name"] for j in jobs if (j.get("status") or {}).get("phase") == "dispatched"}

        deadline = time.monotonic() + 60
        while not dispatched():  # the first bind is visible: the pass that made it is still writing
            assert proc.poll() is None and time.monotonic() < deadline, log.read_text()[-3000:]
            time.sleep(0.02)
        proc.terminate()
        assert proc.wait(timeout=30) == 0, log.read_text()[-3000:]
        bound = dispatched()
        events = core.list_namespaced_event(namespace, field_selector="reason=Bound").items
        missing = bound - {e.involved_object.name for e in events}
        assert not missing, f"bound without their Bound Event: {sorted(missing)}\n{log.read_text()[-3000:]}"
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()
        for cell in cells:
            with contextlib.suppress(client.ApiException):
                api.delete_cluster_custom_object(GROUP, VERSION, CELLS, cell)

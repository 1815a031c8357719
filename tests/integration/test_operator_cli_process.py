"""`armnet operator` as a real process: it binds a job, serves /metrics, and exits at SIGTERM."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
import urllib.request
import uuid
from datetime import UTC, datetime
from typing import Any

import pytest
import yaml

pytestmark = pytest.mark.integration


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


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
        now = datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
        k8s.kubectl("apply", "-f", "-", input=yaml.safe_dump({
            "apiVersion": "armnet.io/v1alpha1", "kind": "Cell", "metadata": {"name": cell},
            "spec": {"embodiment": embodiment, "nodeName": "host-1"}}))
        k8s.kubectl("patch", "cell", cell, "--subresource=status", "--type=merge",
                    "-p", json.dumps({"status": {"lastHeartbeatTime": now}}))
        k8s.kubectl("apply", "-n", namespace, "-f", "-", input=yaml.safe_dump({
            "apiVersion": "armnet.io/v1alpha1", "kind": "RobotJob", "metadata": {"name": "cli-job"},
            "spec": {"image": "localhost/armnet-test:dev", "embodiment": embodiment}}))
        deadline = time.monotonic() + 60
        phase = None
        while time.monotonic() < deadline and phase != "dispatched":
            time.sleep(0.5)
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
        proc.terminate()
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        k8s.kubectl("delete", "cell", cell, "--ignore-not-found", "--wait=false", check=False)

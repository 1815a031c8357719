"""The RobotJob CRD deleted and re-applied under a running `armnet operator`.

Runs on a control plane of its own: deleting the CRD deletes every RobotJob,
which must never touch the session's shared control plane and its tests.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pytest
import yaml
from armnet_core.api import GROUP, ROBOTJOBS
from armnet_core.times import kube_time
from armnet_testbed.kube import ControlPlane

from tests.support.processes import stop_process

pytestmark = pytest.mark.integration

CRD = Path(__file__).resolve().parents[2] / "crds" / "robotjob.yaml"
CRD_NAME = f"{ROBOTJOBS}.{GROUP}"


@pytest.fixture
def own_plane() -> Iterator[ControlPlane]:
    plane = ControlPlane().start()
    try:
        yield plane
    finally:
        plane.stop()


def wait(what: str, check: Any, proc: subprocess.Popen[str], log: Path, timeout: float = 60) -> Any:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        assert proc.poll() is None, f"the operator exited ({proc.returncode}):\n{log.read_text()[-4000:]}"
        if result := check():
            return result
        time.sleep(0.3)
    raise AssertionError(f"timed out waiting for {what}:\n{log.read_text()[-4000:]}")


def test_the_operator_outlives_its_crd_and_binds_again_once_it_is_back(own_plane: ControlPlane, tmp_path: Path) -> None:
    k8s = own_plane
    ns = k8s.create_namespace("crd")
    log = tmp_path / "operator.log"
    argv = [sys.executable, "-m", "armnet_cli.main", "operator", "--kubeconfig", str(k8s.kubeconfig),
            "--namespaces", ns, "--lease-namespace", ns, "--metrics-port", "0", "--reconcile-period", "0.5",
            "--lease-duration", "3", "--heartbeat-timeout", "30", "--cancel-force-after", "1"]
    with log.open("w") as out:
        proc = subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT, text=True,
                                env={**os.environ, "KUBECONFIG": str(k8s.kubeconfig)})
    try:
        def apply(doc: dict[str, Any]) -> None:
            k8s.kubectl("apply", "-f", "-", input=yaml.safe_dump(doc))

        beaten = [0.0]

        def beat() -> None:
            now = kube_time(datetime.now(UTC))
            k8s.kubectl("patch", "cell", "c1", "--subresource=status", "--type=merge",
                        "-p", json.dumps({"status": {"lastHeartbeatTime": now}}))
            beaten[0] = time.monotonic()

        def bound(name: str) -> bool:
            """The job is dispatched; meanwhile the cell's heartbeat is kept fresh, as its agent would: an
            operator that took longer than the heartbeat timeout to start (Python and kopf imports at load
            ~12 took over 30 s) must find the cell online, not one beat at the test's start gone stale."""
            if time.monotonic() - beaten[0] > 5:
                beat()
            return phase(name) == "dispatched"

        def job(name: str) -> None:
            apply({"apiVersion": "armnet.io/v1alpha1", "kind": "RobotJob", "metadata": {"name": name, "namespace": ns},
                   "spec": {"image": "localhost/armnet-test:dev", "embodiment": "test/crd"}})

        def phase(name: str) -> str:
            return k8s.kubectl("get", "rj", name, "-n", ns, "-o", "jsonpath={.status.phase}", check=False).stdout

        apply({"apiVersion": "armnet.io/v1alpha1", "kind": "Cell", "metadata": {"name": "c1"},
               "spec": {"embodiment": "test/crd", "nodeName": "h"}})
        beat()
        job("before")
        wait("the first job bound", lambda: bound("before"), proc, log)
        k8s.kubectl("patch", "rj", "before", "-n", ns, "--subresource=status", "--type=merge",
                    "-p", '{"status":{"phase":"succeeded","finishedAt":"2026-01-01T00:00:00Z"}}')
        wait("the cell released", lambda: not k8s.kubectl(
            "get", "cell", "c1", "-o", "jsonpath={.status.currentJob}").stdout, proc, log)

        k8s.kubectl("delete", "crd", CRD_NAME, "--timeout=60s")
        wait("the operator saying the CRD is missing", lambda: f"{CRD_NAME} are not served" in log.read_text(),
             proc, log)
        k8s.kubectl("apply", "--server-side", "-f", str(CRD))
        k8s.wait_established(f"crd/{CRD_NAME}")
        beat()
        wait("the CRD served again", lambda: k8s.kubectl("get", "rj", "-n", ns, check=False).returncode == 0, proc, log)
        job("after")
        wait("a new job bound after the CRD came back", lambda: bound("after"), proc, log)
        # kopf may miss the CRD's return (it rescans discovery on CRD events only, and the last
        # one can precede discovery); the operator restarts its watches rather than trust it:
        # on the CRD's new uid, or earlier, when kopf's own watch failed on the 404 and stopped
        # (then the operator runs kopf again after a backoff; seen in a loaded CI run).
        text = log.read_text()
        assert "restarting the watches" in text or "kopf stopped (404" in text, text[-3000:]
        assert "starting the operator's watches and reconcile loop again" in text

        # Deleted and created again between two looks (kubectl replace --force, a GitOps sync):
        # a new uid is a return all the same.
        k8s.kubectl("patch", "rj", "after", "-n", ns, "--subresource=status", "--type=merge",
                    "-p", '{"status":{"phase":"succeeded","finishedAt":"2026-01-01T00:00:00Z"}}')
        wait("the cell released again", lambda: not k8s.kubectl(
            "get", "cell", "c1", "-o", "jsonpath={.status.currentJob}").stdout, proc, log)
        restarts = log.read_text().count("reconcile loop again")
        k8s.kubectl("replace", "--force", "-f", str(CRD))
        k8s.wait_established(f"crd/{CRD_NAME}")
        wait("the CRD served once more", lambda: k8s.kubectl("get", "rj", "-n", ns, check=False).returncode == 0,
             proc, log)
        wait("the watches restarted for the replaced CRD",
             lambda: log.read_text().count("reconcile loop again") > restarts, proc, log)
        beat()
        job("replaced")
        wait("a new job bound after the CRD was replaced", lambda: bound("replaced"), proc, log)
        proc.terminate()  # restarted twice, it still ends cleanly at SIGTERM
        assert proc.wait(timeout=20) == 0, log.read_text()[-3000:]
    finally:
        stop_process(proc)

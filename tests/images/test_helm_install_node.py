"""`helm install` of the chart for real: the shipped images as pods on the test-bed node.

What runs: the test bed's apiserver and node (containerd + kubelet), plus
kube-controller-manager and kube-scheduler for this test alone (the chart's Deployment
and DaemonSet become pods only through them; tests/testbed/controllers.py); the
operator and agent images built from images/ and imported into the node's containerd.

Test-bed choices (docs/helm.md, "The real install on the test bed"): the test bed has
no kube-proxy and pods get an isolated bridge, so the `kubernetes` Service is not
reachable from a pod; the operator and agent run with ``hostNetwork: true`` and
``KUBERNETES_SERVICE_HOST/PORT`` set to the apiserver's loopback address. The agent
still launches job containers through a Docker-API engine (the session's Podman
socket, mounted in); the pod launcher replaces that. The job image is the example
customer image (images/example-job) built on the shipped runtime image.
"""

from __future__ import annotations

import json
import subprocess
import tempfile
import time
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any
from urllib.parse import urlparse

import pytest
import yaml

from tests.integration.test_helm_chart import CHART, helm_binary
from tests.integration.test_helm_lifecycle import helm_on
from tests.testbed.controllers import WorkloadControllers
from tests.testbed.kube import ControlPlane
from tests.testbed.node import Node
from tests.testbed.plugin import Podman
from tests.testbed.procs import free_port

pytestmark = [pytest.mark.node, pytest.mark.container, pytest.mark.timeout(1800)]

ROBOT_HOST_LABEL = "armnet.io/robot-host"


def wait_for(what: str, predicate: Callable[[], Any], timeout: float, on_timeout: Callable[[], str]) -> Any:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.5)
    raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}\n{on_timeout()}")


def get_json(k8s: ControlPlane, *args: str) -> Any:
    result = k8s.kubectl("get", *args, "-o", "json", check=False)
    return json.loads(result.stdout) if result.returncode == 0 else None


def common_tag(podman: Podman, images: list[str]) -> str:
    """One tag on every image (the chart has one image.tag): the joined content hashes."""
    tag = "it-" + "".join(image.rsplit(":", 1)[1][:6] for image in images)
    for image in images:
        podman.client.images.get(image).tag(image.rsplit(":", 1)[0], tag)
    return tag


@pytest.fixture
def release(k8s: ControlPlane, k8s_node: Node, podman: Podman, operator_image: str,
            agent_image: str, runtime_image: str) -> Iterator[dict[str, Any]]:
    """The chart installed, its pods running on the node; everything removed afterwards."""
    tag = common_tag(podman, [operator_image, agent_image])
    for image in (operator_image, agent_image):
        k8s_node.import_image(f"{image.rsplit(':', 1)[0]}:{tag}")
    system = k8s.create_namespace("armnet-system")
    tenant = k8s.create_namespace("tenant")
    name = f"it-{uuid.uuid4().hex[:6]}"
    api = urlparse(k8s.url)
    to_api = {"KUBERNETES_SERVICE_HOST": api.hostname, "KUBERNETES_SERVICE_PORT": str(api.port)}
    host = Path(tempfile.mkdtemp(prefix="armnet-it-"))
    engine_dir = str(podman.socket_path.parent)
    values = {
        "image": {"operatorRepository": operator_image.rsplit(":", 1)[0],
                  "agentRepository": agent_image.rsplit(":", 1)[0], "tag": tag, "pullPolicy": "Never"},
        "jobNamespaces": [{"name": tenant}],
        "crds": {"install": False},  # the test bed applied them (test_helm_lifecycle: adoption)
        "operator": {"replicas": 1, "hostNetwork": True, "metricsPort": free_port(), "extraEnv": to_api,
                     "readinessProbe": {"initialDelaySeconds": 1, "periodSeconds": 2,
                                        "failureThreshold": 3}},
        "agent": {"hostNetwork": True, "metricsPort": free_port(),
                  "extraArgs": ["--verbose", "--heartbeat-period", "2"],
                  "calibration": {"hostPath": str(host / "calibration"),
                                  "mountPath": str(host / "calibration")},
                  "cache": {"hostPath": str(host / "cache"), "mountPath": str(host / "cache")},
                  # The test node's kubelet keeps its pods under its own --root-dir.
                  "kubeletRootDir": str(k8s_node.workdir / "kubelet"),
                  "env": {**to_api, "ARMNET_AGENT_STATE_DIR": str(host / "cache"),
                          "ARMNET_AGENT_CALIBRATION_DIR": str(host / "calibration"),
                          "ARMNET_AGENT_ENGINE_URL": f"unix://{podman.socket_path}"},
                  "extraVolumes": [{"name": "engine", "hostPath": {"path": engine_dir, "type": "Directory"}}],
                  "extraVolumeMounts": [{"name": "engine", "mountPath": engine_dir}]},
    }
    k8s.kubectl("label", "node", k8s_node.name, f"{ROBOT_HOST_LABEL}=true", "--overwrite")
    controllers = WorkloadControllers(plane=k8s).start()
    job_image = "localhost/armnet-example-job:it"
    podman.client.images.build(path=str(CHART.parents[1] / "images" / "example-job"), tag=job_image,
                               rm=True, dockerfile="Containerfile", buildargs={"RUNTIME": runtime_image},
                               network_mode="none")
    state = {"job_image": job_image, "k8s": k8s, "node": k8s_node, "system": system, "tenant": tenant, "name": name,
             "values": values, "controllers": controllers, "host": host}
    try:
        helm_on(k8s, "install", name, str(CHART), "-n", system, values=values)
        yield state
    finally:
        subprocess.run([str(helm_binary()), "uninstall", name, "-n", system, "--wait", "--timeout",
                        "60s", f"--kubeconfig={k8s.kubeconfig}"], capture_output=True, timeout=120,
                       check=False)
        k8s.kubectl("delete", "pods", "--all", "-n", system, "--grace-period=1", "--wait=false",
                    check=False)
        wait_for("the release's pods to go", lambda: not (get_json(k8s, "pods", "-n", system) or
                                                          {"items": []})["items"],
                 60, controllers.log_tail)
        controllers.stop()
        k8s.kubectl("label", "node", k8s_node.name, f"{ROBOT_HOST_LABEL}-", check=False)
        for cell in (get_json(k8s, "cells") or {"items": []})["items"]:
            if cell["metadata"]["name"].startswith(name):
                k8s.kubectl("delete", "cell", cell["metadata"]["name"], "--wait=false", check=False)
        k8s.delete_namespace(tenant)
        k8s.delete_namespace(system)


def pod_of(state: dict[str, Any], component: str) -> dict[str, Any] | None:
    listed = get_json(state["k8s"], "pods", "-n", state["system"], "-l",
                      f"app.kubernetes.io/component={component},app.kubernetes.io/instance={state['name']}")
    items = (listed or {"items": []})["items"]
    return items[0] if items else None


def ready(pod: dict[str, Any] | None) -> bool:
    conditions = ((pod or {}).get("status") or {}).get("conditions") or []
    return any(c["type"] == "Ready" and c["status"] == "True" for c in conditions)


def diagnose(state: dict[str, Any]) -> str:
    k8s = state["k8s"]
    parts = [state["controllers"].log_tail()]
    for component in ("operator", "agent"):
        pod = pod_of(state, component)
        parts.append(f"--- {component} pod status: {json.dumps((pod or {}).get('status'))[:2000]}")
        if pod:
            logs = k8s.kubectl("logs", "-n", state["system"], pod["metadata"]["name"], "--tail=40",
                               check=False)
            parts.append(f"--- {component} logs:\n{logs.stdout}{logs.stderr}")
    parts.append(k8s.kubectl("get", "events", "-n", state["system"], check=False).stdout[-3000:])
    return "\n".join(parts)


def test_helm_install_runs_a_tenants_job_on_a_simulated_cell_with_the_shipped_images(
        release: dict[str, Any]) -> None:
    k8s: ControlPlane = release["k8s"]
    node: Node = release["node"]
    operator = wait_for("the operator pod Ready", lambda: (p := pod_of(release, "operator")) and ready(p) and p,
                        240, lambda: diagnose(release))
    agent = wait_for("the agent pod Running", lambda: (p := pod_of(release, "agent")) and
                     (p.get("status") or {}).get("phase") == "Running" and p, 120, lambda: diagnose(release))
    cell = f"{release['name']}-sim"
    k8s.kubectl("apply", "-f", "-", input=yaml.safe_dump({
        "apiVersion": "armnet.io/v1alpha1", "kind": "Cell", "metadata": {"name": cell},
        "spec": {"nodeName": node.name, "simulated": True, "embodiment": "lerobot/so-101",
                 "robot": {"robotId": f"{cell}-arm", "safetyLimit": 10}}}))
    wait_for(f"cell {cell} Ready", lambda: ((get_json(k8s, "cell", cell) or {}).get("status") or {})
             .get("phase") == "Ready", 180, lambda: diagnose(release))
    k8s.kubectl("apply", "-n", release["tenant"], "-f", "-", input=yaml.safe_dump({
        "apiVersion": "armnet.io/v1alpha1", "kind": "RobotJob", "metadata": {"name": "hello"},
        "spec": {"image": release["job_image"], "args": {"name": "helm"}, "embodiment": "lerobot/so-101",
                 "timeoutSeconds": 60}}))
    job = wait_for("the job bound to the cell", lambda: (j := get_json(
        k8s, "robotjob", "hello", "-n", release["tenant"])) and (j.get("status") or {}).get("cellName") and j,
        60, lambda: diagnose(release))

    done = wait_for("the job to finish", lambda: (j := get_json(
        k8s, "robotjob", "hello", "-n", release["tenant"])) and (j.get("status") or {}).get("phase") in
        ("succeeded", "failed") and j, 180, lambda: diagnose(release))
    assert operator["spec"]["nodeName"] == agent["spec"]["nodeName"] == node.name
    assert [c["image"] for c in operator["spec"]["containers"]] == [
        f"{release['values']['image']['operatorRepository']}:{release['values']['image']['tag']}"]
    assert operator["spec"]["securityContext"]["runAsUser"] == 65532
    assert job["status"]["cellName"] == cell
    assert done["status"]["phase"] == "succeeded"
    assert done["status"]["result"]["returnValue"] == {"greeting": "hello, helm",
                                                       "job_id": done["status"]["jobId"]}

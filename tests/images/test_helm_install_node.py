"""`helm install` of the chart for real: the shipped images as pods on the test-bed node.

What runs: the test bed's apiserver and node (containerd + kubelet), plus
kube-controller-manager and kube-scheduler for this module alone (the chart's Deployment
and DaemonSet become pods only through them; testbed/armnet_testbed/controllers.py); the
operator and agent images built from images/ and imported into the node's containerd.

The agent runs the chart's default, the pod launcher: each job is a pod on the agent's
node, the customer's image as its container and the agent image as its connector
sidecar, which also runs the simulated cell's simulator (``agent.podSimulator``). The
customer images: the bus-loop example (LeRobot's own FeetechMotorsBus moving the arm
through the connector) on the shipped runtime image's LeRobot variant, and the example
customer image (images/example-job) on the shipped runtime image.

Test-bed choices (docs/helm.md, "The real install on the test bed"): the test bed has
no kube-proxy and pods get an isolated bridge, so the `kubernetes` Service is not
reachable from a pod; the operator and agent run with ``hostNetwork: true`` and
``KUBERNETES_SERVICE_HOST/PORT`` set to the apiserver's loopback address.

One release per module, its tests in order (they share the ~minute of setup): a
tenant's job runs; an evaluation of ten rollouts runs with nobody at the cell (the
completion monitor and the scripted reset in the job pod's sidecar); an upgrade rolls
the operator under a running job; the uninstall keeps the CRDs and the jobs.
"""

from __future__ import annotations

import copy
import json
import shutil
import subprocess
import tempfile
import time
import urllib.request
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any
from urllib.parse import urlparse

import pytest
import yaml
from armnet_core.api import CELLS, GROUP, ROBOTJOBS, VERSION
from armnet_testbed.controllers import WorkloadControllers
from armnet_testbed.kube import ControlPlane
from armnet_testbed.node import Node
from armnet_testbed.plugin import Podman
from armnet_testbed.procs import free_port
from armnet_testbed.release_images import forget_superseded_tags, release_images, repository

from tests.support.helm import CHART, CRDS, adopt_crds, helm_binary, helm_on
from tests.support.unattended import (
    CAMERAS,
    SCRIPTED_RESET,
    check_scored_reset_scored,
    target_completion,
)

pytestmark = [pytest.mark.node, pytest.mark.container, pytest.mark.timeout(1800)]

ROBOT_HOST_LABEL = "armnet.io/robot-host"
EVALUATION_ROLLOUTS = 10


def wait_for(what: str, predicate: Callable[[], Any], timeout: float, on_timeout: Callable[[], str]) -> Any:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.5)
    raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}\n{on_timeout()}")


_CLIENTS: dict[int, Any] = {}


def _api(k8s: ControlPlane) -> Any:
    """One API client per control plane (a dataclass: not hashable, so keyed by identity)."""
    if id(k8s) not in _CLIENTS:
        _CLIENTS[id(k8s)] = k8s.api_client()
    return _CLIENTS[id(k8s)]


def get_json(k8s: ControlPlane, kind: str, *args: str) -> Any:
    """What ``kubectl get KIND [NAME] [-n NS] [-l SELECTOR] -o json`` prints, or None where it fails.

    Through the API client: the waits poll twice a second, and a kubectl process per
    read cost ~70 ms of CPU, on two cores shared with the suite's other sessions.
    """
    from kubernetes import client
    from kubernetes.client.exceptions import ApiException

    name, namespace, selector = None, "", None
    rest = list(args)
    while rest:
        arg = rest.pop(0)
        if arg == "-n":
            namespace = rest.pop(0)
        elif arg == "-l":
            selector = rest.pop(0)
        else:
            name = arg
    api = _api(k8s)
    raw = {"_preload_content": False}  # the server's JSON as is (camelCase), as kubectl prints it
    kind = kind.removesuffix("s")
    try:
        if kind == "pod" and name:
            response = client.CoreV1Api(api).read_namespaced_pod(name, namespace, **raw)
        elif kind == "pod":
            response = client.CoreV1Api(api).list_namespaced_pod(namespace, label_selector=selector or "", **raw)
        elif kind == "deployment":
            response = client.AppsV1Api(api).read_namespaced_deployment(name, namespace, **raw)
        elif kind == "cell" and name:
            response = client.CustomObjectsApi(api).get_cluster_custom_object(GROUP, VERSION, CELLS,
                                                                             name, **raw)
        elif kind == "cell":
            response = client.CustomObjectsApi(api).list_cluster_custom_object(GROUP, VERSION, CELLS, **raw)
        elif kind == "robotjob" and name:
            response = client.CustomObjectsApi(api).get_namespaced_custom_object(
                GROUP, VERSION, namespace, ROBOTJOBS, name, **raw)
        elif kind == "robotjob":
            response = client.CustomObjectsApi(api).list_namespaced_custom_object(
                GROUP, VERSION, namespace, ROBOTJOBS, **raw)
        else:
            raise ValueError(f"get_json does not read {kind!r}: add it")
    except ApiException:
        return None
    return json.loads(response.data)


@pytest.fixture(scope="module")
def release(k8s: ControlPlane, k8s_node: Node, podman: Podman) -> Iterator[dict[str, Any]]:
    """The chart installed, its pods running on the node; everything removed afterwards.

    Its images are in the node's store already when setup ran (testbed/armnet_testbed/release_images.py):
    the import here then finds nothing to do.
    """
    images = release_images(podman.client)
    forget_superseded_tags(podman.client, images)
    k8s_node.forget_images(images.is_superseded)
    k8s_node.import_images(*images.all())
    system = k8s.create_namespace("armnet-system")
    tenant = k8s.create_namespace("tenant")
    name = f"it-{uuid.uuid4().hex[:6]}"
    api = urlparse(k8s.url)
    to_api = {"KUBERNETES_SERVICE_HOST": api.hostname, "KUBERNETES_SERVICE_PORT": str(api.port)}
    host = Path(tempfile.mkdtemp(prefix="armnet-it-"))
    values = {
        "image": {"operatorRepository": repository(images.operator),
                  "agentRepository": repository(images.agent), "tag": images.tag, "pullPolicy": "Never"},
        "jobNamespaces": [{"name": tenant}],
        # With hostNetwork the operator's ports are host ports: free ones, changed on upgrade (one node).
        "admissionWebhook": {"port": free_port()},
        "operator": {"replicas": 1, "hostNetwork": True, "metricsPort": free_port(), "extraEnv": to_api,
                     "readinessProbe": {"initialDelaySeconds": 1, "periodSeconds": 2,
                                        "failureThreshold": 3}},
        # The defaults otherwise: the pod launcher, the agent image as the connector sidecar.
        "agent": {"hostNetwork": True, "metricsPort": free_port(), "jobImagePullPolicy": "Never",
                  "nodeBoundPods": True,
                  "extraArgs": ["--verbose", "--heartbeat-period", "2"],
                  "calibration": {"hostPath": str(host / "calibration"),
                                  "mountPath": str(host / "calibration")},
                  "cache": {"hostPath": str(host / "cache"), "mountPath": str(host / "cache")},
                  # The test node's kubelet keeps its pods under its own --root-dir.
                  "kubeletRootDir": str(k8s_node.workdir / "kubelet"),
                  "env": {**to_api, "ARMNET_AGENT_STATE_DIR": str(host / "cache"),
                          "ARMNET_AGENT_CALIBRATION_DIR": str(host / "calibration")}},
    }
    k8s.kubectl("label", "node", k8s_node.name, f"{ROBOT_HOST_LABEL}=true", "--overwrite")
    controllers = WorkloadControllers(plane=k8s).start()
    state = {"job_image": images.example_job, "bus_loop_image": images.bus_loop,
             "unattended_eval_image": images.unattended_eval, "k8s": k8s,
             "node": k8s_node, "system": system, "tenant": tenant, "name": name, "values": values,
             "controllers": controllers, "host": host, "connector_image": images.agent}
    try:
        # The test bed applied the CRDs; the release adopts them as docs/helm.md says (its uninstall must keep them).
        adopt_crds(k8s, name, system)
        helm_on(k8s, "install", name, str(CHART), "-n", system, values=values)
        yield state
    finally:
        subprocess.run([str(helm_binary()), "uninstall", name, "-n", system, "--wait", "--timeout",
                        "60s", f"--kubeconfig={k8s.kubeconfig}"], capture_output=True, timeout=120,
                       check=False)
        for namespace in (system, tenant):
            k8s.kubectl("delete", "pods", "--all", "-n", namespace, "--grace-period=1", "--wait=false",
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
        shutil.rmtree(host, ignore_errors=True)


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
    for pod in (get_json(k8s, "pods", "-n", state["tenant"]) or {"items": []})["items"]:
        pod_name = pod["metadata"]["name"]
        parts.append(f"--- job pod {pod_name} status: {json.dumps(pod.get('status'))[:2000]}")
        for container in ("connector", "job"):
            logs = k8s.kubectl("logs", "-n", state["tenant"], pod_name, "-c", container, "--tail=30", check=False)
            parts.append(f"--- {pod_name} {container} logs:\n{logs.stdout}{logs.stderr}")
    parts.append(k8s.kubectl("get", "events", "-n", state["system"], check=False).stdout[-3000:])
    parts.append(k8s.kubectl("get", "events", "-n", state["tenant"], check=False).stdout[-3000:])
    return "\n".join(parts)


def submit(state: dict[str, Any], name: str, args: dict[str, Any], timeout: int = 60, image: str | None = None,
           task: str | None = None) -> None:
    spec = {"image": image or state["job_image"], "args": args, "embodiment": "lerobot/so-101", "timeoutSeconds": timeout}
    state["k8s"].kubectl("apply", "-n", state["tenant"], "-f", "-", input=yaml.safe_dump({
        "apiVersion": "armnet.io/v1alpha1", "kind": "RobotJob", "metadata": {"name": name},
        "spec": {**spec, **({"task": task} if task else {})}}))


def job_of(state: dict[str, Any], name: str) -> dict[str, Any] | None:
    found: dict[str, Any] | None = get_json(state["k8s"], "robotjob", name, "-n", state["tenant"])
    return found


def phase(job: dict[str, Any] | None) -> str | None:
    return ((job or {}).get("status") or {}).get("phase")


def wait_finished(state: dict[str, Any], name: str, timeout: float) -> dict[str, Any]:
    done: dict[str, Any] = wait_for(f"job {name} to finish", lambda: (j := job_of(state, name)) and phase(j) in
                                    ("succeeded", "failed", "cancelled") and j, timeout, lambda: diagnose(state))
    return done


def test_helm_install_runs_a_tenants_bus_loop_job_as_a_pod_of_the_shipped_images_on_a_simulated_cell(
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
    # Generous: a loaded host takes a minute or more to import LeRobot in the pod.
    submit(release, "bus-loop", {"degrees": 4}, timeout=240, image=release["bus_loop_image"])
    job = wait_for("the job bound to the cell", lambda: (j := job_of(release, "bus-loop")) and
                   (j.get("status") or {}).get("cellName") and j, 60, lambda: diagnose(release))
    pod_name = f"armnet-{job['metadata']['uid']}"
    # The agent deletes the job's pod once it has written the result: look at it while it exists.
    job_pod = wait_for(f"the job's pod {pod_name}", lambda: get_json(k8s, "pod", pod_name, "-n", release["tenant"]),
                       120, lambda: diagnose(release))

    done = wait_finished(release, "bus-loop", 360)
    (connector,) = job_pod["spec"]["initContainers"]
    (customer,) = job_pod["spec"]["containers"]
    assert operator["spec"]["nodeName"] == agent["spec"]["nodeName"] == job_pod["spec"]["nodeName"] == node.name
    assert [c["image"] for c in operator["spec"]["containers"]] == [
        f"{release['values']['image']['operatorRepository']}:{release['values']['image']['tag']}"]
    assert operator["spec"]["securityContext"]["runAsUser"] == 65532
    assert job["status"]["cellName"] == cell
    assert (customer["image"], connector["image"]) == (release["bus_loop_image"], release["connector_image"])
    assert connector["restartPolicy"] == "Always"  # a native sidecar
    assert customer["securityContext"]["runAsUser"] == 65532
    # The simulator runs in the sidecar: no host device reaches the pod.
    assert not [v for v in job_pod["spec"]["volumes"] if v.get("hostPath", {}).get("type") == "CharDevice"]
    assert done["status"]["phase"] == "succeeded", json.dumps(done["status"])[:2000]
    # The arm moved: LeRobot's bus in the job pod, the connector and the simulator in its sidecar.
    finals = done["status"]["result"]["returnValue"]["final_positions"]
    assert set(finals) >= {"shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll"}
    assert done["status"]["result"]["safety"]["policy"] == "clamp"  # the sidecar's record reached the status
    # The DaemonSet's agent reached the pod's observer socket through its read-only kubelet mount.
    port = release["values"]["agent"]["metricsPort"]
    metrics = urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=10).read().decode()
    assert observer_requests(metrics, "ok") > 0, metrics[-3000:]
    assert observer_requests(metrics, "unreachable") == 0


def observer_requests(metrics: str, result: str) -> float:
    prefix = f'armnet_agent_sidecar_observer_requests_total{{result="{result}"}} '
    return sum(float(line[len(prefix):]) for line in metrics.splitlines() if line.startswith(prefix))


def test_an_evaluation_pod_runs_scored_reset_scored_with_nobody_at_the_cell(release: dict[str, Any]) -> None:
    """The pod launcher's unattended evaluation: the cell's completion monitor and scripted reset in the job
    pod's connector sidecar (with the simulator, so its camera draws the arm), ten rollouts, no operator input
    (this release has no NATS: none can reach the cell)."""
    k8s: ControlPlane = release["k8s"]
    cell = f"{release['name']}-eval"
    k8s.kubectl("apply", "-f", "-", input=yaml.safe_dump({
        "apiVersion": "armnet.io/v1alpha1", "kind": "Cell", "metadata": {"name": cell},
        "spec": {"nodeName": release["node"].name, "simulated": True, "embodiment": "lerobot/so-101",
                 "task": "evaluation", "robot": {"robotId": f"{cell}-arm", "safetyLimit": 10},
                 "cameras": CAMERAS, "completion": target_completion(), "reset": SCRIPTED_RESET}}))
    wait_for(f"cell {cell} Ready", lambda: ((get_json(k8s, "cell", cell) or {}).get("status") or {})
             .get("phase") == "Ready", 180, lambda: diagnose(release))

    submit(release, "unattended-eval", {"rollouts": EVALUATION_ROLLOUTS}, timeout=300,
           image=release["unattended_eval_image"], task="evaluation")
    try:
        done = wait_finished(release, "unattended-eval", 420)
    finally:
        k8s.kubectl("delete", "cell", cell, "--wait=false", check=False)  # the later jobs go to the -sim cell

    assert done["status"]["phase"] == "succeeded", json.dumps(done["status"])[:3000]
    assert done["status"]["cellName"] == cell
    check_scored_reset_scored(done["status"], EVALUATION_ROLLOUTS)


def test_helm_upgrade_rolls_the_operator_while_a_job_runs_and_the_job_still_succeeds(
        release: dict[str, Any]) -> None:
    k8s: ControlPlane = release["k8s"]
    before = pod_of(release, "operator")
    assert before is not None and ready(before), "the install test leaves a Ready operator"
    submit(release, "through-upgrade", {"name": "upgrade", "seconds": 50}, timeout=180)
    wait_for("the job running", lambda: phase(job_of(release, "through-upgrade")) == "running", 180,
             lambda: diagnose(release))
    values = copy.deepcopy(release["values"])
    # A changed value in the operator's pod template: its ports (with hostNetwork on one node the new pod,
    # which starts before the old one stops, needs ports of its own anyway).
    values["operator"]["metricsPort"] = free_port()
    values["admissionWebhook"]["port"] = free_port()
    helm_on(k8s, "upgrade", release["name"], str(CHART), "-n", release["system"], values=values)

    def rolled() -> dict[str, Any] | None:
        listed = get_json(k8s, "pods", "-n", release["system"], "-l",
                          f"app.kubernetes.io/component=operator,app.kubernetes.io/instance={release['name']}")
        pods = (listed or {"items": []})["items"]
        if len(pods) == 1 and pods[0]["metadata"]["uid"] != before["metadata"]["uid"] and ready(pods[0]):
            return dict(pods[0])
        return None

    after = wait_for("the operator rolled (a new pod Ready, the old one gone)", rolled, 180, lambda: diagnose(release))
    during = phase(job_of(release, "through-upgrade"))
    done = wait_finished(release, "through-upgrade", 180)

    assert [p["containerPort"] for p in after["spec"]["containers"][0]["ports"] if p["name"] == "metrics"] == [
        values["operator"]["metricsPort"]]
    assert during == "running", f"the job was {during} when the roll ended: the roll did not overlap the job"
    assert done["status"]["phase"] == "succeeded", json.dumps(done["status"])[:2000]
    assert done["status"]["result"]["returnValue"]["greeting"] == "hello, upgrade"


def test_helm_uninstall_keeps_the_crds_the_cells_and_the_tenants_robotjobs(release: dict[str, Any]) -> None:
    k8s: ControlPlane = release["k8s"]
    helm_on(k8s, "uninstall", release["name"], "-n", release["system"], "--wait", "--timeout", "90s")

    jobs = (get_json(k8s, "robotjobs", "-n", release["tenant"]) or {"items": []})["items"]
    assert k8s.kubectl("get", "crd", *CRDS, check=False).returncode == 0
    assert get_json(k8s, "cell", f"{release['name']}-sim") is not None  # the platform team's Cells too
    assert {j["metadata"]["name"]: phase(j) for j in jobs} == {
        "bus-loop": "succeeded", "unattended-eval": "succeeded", "through-upgrade": "succeeded"}
    assert all(j["status"]["result"]["returnValue"] for j in jobs)  # their results kept with them
    assert get_json(k8s, "deployment", f"{release['name']}-armnet-operator", "-n", release["system"]) is None

"""The agent's cell device plugin with the test bed's real kubelet: registration, allocation, health, restart.

The plugin (``deviceplugin.server.DevicePlugins``, as ``armnet agent --launcher
pod`` runs it) serves one cell whose arm is a real pty of this test, reached
through a symlink (the way ``/dev/serial/by-id/...`` reaches ``/dev/ttyUSB0``),
so that removing the symlink makes the device vanish. Pods request the cell's
resource ``armnet.io/cell-<cell>`` and open the arm at ``/dev/armnet/arm``.

Pods here name their node (``spec.nodeName``; no scheduler runs, as for the
agent's job pods), so a pod the kubelet cannot give the device to is refused at
admission (phase ``Failed``) rather than left ``Pending`` by a scheduler.
"""

from __future__ import annotations

import json
import os
import select
import tempfile
import time
import tty
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from armnet_core.api import CELL_RESOURCE_PREFIX
from armnet_node.deviceplugin.decide import cell_device_paths
from armnet_node.deviceplugin.server import DevicePlugins
from armnet_node.metrics import AgentMetrics
from armnet_testbed.images import BASE_IMAGE
from armnet_testbed.kube import ControlPlane
from armnet_testbed.node import DEVICE_PLUGIN_DIR, Node

from tests.support.waiting import wait_for

pytestmark = [pytest.mark.node, pytest.mark.integration]

CELL = "dp-node"
RESOURCE = f"{CELL_RESOURCE_PREFIX}{CELL}"

# Reads one line from the arm's device and answers it, then holds the device HOLD seconds.
ANSWERS_ON_THE_ARM = """
import os, select, time
fd = os.open("/dev/armnet/arm", os.O_RDWR | os.O_NOCTTY)
ready, _, _ = select.select([fd], [], [], 20)
line = os.read(fd, 64).decode().strip() if ready else "nothing"
os.write(fd, ("pong " + line + chr(10)).encode())
print("read", line, flush=True)
time.sleep(float(os.environ["HOLD"]))
"""


@dataclass
class Bed:
    node: Node
    k8s: ControlPlane
    namespace: str
    plugins: DevicePlugins
    metrics: AgentMetrics
    master: int
    link: Path

    def sample(self, name: str, **labels: str) -> float:
        return self.metrics.registry.get_sample_value(name, {"cell": CELL, **labels}) or 0.0

    def pod(self, name: str, hold: float = 0) -> dict[str, Any]:
        container = {"name": "connector", "image": BASE_IMAGE, "imagePullPolicy": "Never",
                     "command": ["python3", "-c", ANSWERS_ON_THE_ARM], "env": [{"name": "HOLD", "value": str(hold)}],
                     "securityContext": {"privileged": False, "allowPrivilegeEscalation": False},
                     "resources": {"limits": {RESOURCE: "1"}, "requests": {RESOURCE: "1"}}}
        manifest = self.node.pod_yaml(name, containers=[container], terminationGracePeriodSeconds=0)
        manifest["metadata"]["namespace"] = self.namespace
        self.k8s.kubectl("apply", "-f", "-", input=json.dumps(manifest))
        return manifest

    def wait_pod(self, name: str, phases: tuple[str, ...]) -> dict[str, Any]:
        return self.node.wait_for_pod(self.namespace, name, phases=phases, timeout=60)

    def delete_pod(self, name: str) -> None:
        self.k8s.kubectl("delete", "pod", name, "-n", self.namespace, "--grace-period=0", "--force", check=False)

    def answer_from_the_arm(self) -> bytes:
        """What a pod wrote back on the arm's pty (read from the master side)."""
        got = b""
        deadline = time.monotonic() + 30
        while b"\n" not in got and time.monotonic() < deadline:
            ready, _, _ = select.select([self.master], [], [], 0.5)
            if ready:
                got += os.read(self.master, 256)
        return got


@pytest.fixture(scope="module")
def bed(k8s: ControlPlane, k8s_node: Node) -> Iterator[Bed]:
    namespace = k8s.create_namespace("device-plugin")
    master, slave = os.openpty()
    tty.setraw(slave)  # no echo, no line editing: the pod's bytes arrive as written
    workdir = Path(tempfile.mkdtemp(prefix="armnet-dp-"))
    link = workdir / "usb-armnet-test-arm"
    link.symlink_to(os.ttyname(slave))
    metrics = AgentMetrics()
    plugins = DevicePlugins(metrics, DEVICE_PLUGIN_DIR, check_s=0.3).start()
    plugins.sync({CELL: lambda: cell_device_paths({"arm": str(link)})})
    try:
        yield Bed(k8s_node, k8s, namespace, plugins, metrics, master, link)
    finally:
        plugins.stop()
        k8s.kubectl("delete", "pods", "--all", "-n", namespace, "--grace-period=0", "--force", check=False)
        k8s.delete_namespace(namespace)
        os.close(master)
        os.close(slave)
        link.unlink(missing_ok=True)
        workdir.rmdir()


def test_the_kubelet_advertises_one_device_of_the_cells_resource_after_registration(bed: Bed) -> None:
    assert bed.sample("armnet_agent_device_plugin_registrations_total", result="ok") >= 1

    def advertised() -> dict[str, Any] | None:
        status = (bed.node.node_object() or {}).get("status", {})
        return status if status.get("capacity", {}).get(RESOURCE) == "1" else None

    status = wait_for(advertised, 30, f"the Node's capacity to list {RESOURCE}")
    assert status["allocatable"][RESOURCE] == "1"


def test_a_pod_requesting_the_cell_opens_its_pty_at_the_connector_path_and_a_second_pod_is_refused(bed: Bed) -> None:
    os.write(bed.master, b"ping\n")
    try:
        bed.pod("holder", hold=30)
        bed.wait_pod("holder", ("Running",))
        assert bed.answer_from_the_arm() == b"pong ping\n"
        bed.pod("second")
        refused = bed.wait_pod("second", ("Failed", "Running", "Succeeded"))
        assert refused["status"]["phase"] == "Failed", refused["status"]
        assert RESOURCE in refused["status"].get("message", ""), refused["status"]
    finally:  # the later tests need the cell's one device free
        bed.delete_pod("holder")
        bed.delete_pod("second")


def test_a_vanished_device_path_turns_the_device_unhealthy_and_back(bed: Bed) -> None:
    target = os.readlink(bed.link)
    bed.link.unlink()
    try:
        wait_for(lambda: bed.sample("armnet_agent_device_healthy") == 0 or None, 10, "the device reported unhealthy")
        bed.pod("while-unplugged")
        refused = bed.wait_pod("while-unplugged", ("Failed", "Running", "Succeeded"))
        assert refused["status"]["phase"] == "Failed", refused["status"]
        # The device manager says "unhealthy"; once the Node's status shows the device gone, the
        # kubelet's resource check refuses first ("capacity: 0"): both are the health the plugin sent.
        message = refused["status"].get("message", "")
        assert "unhealthy" in message or "capacity: 0" in message, refused["status"]
    finally:
        bed.link.symlink_to(target)
    wait_for(lambda: bed.sample("armnet_agent_device_healthy") == 1 or None, 10, "the device reported healthy again")
    bed.delete_pod("while-unplugged")


def test_after_a_kubelet_restart_the_plugin_registers_again_and_pods_get_the_device(bed: Bed) -> None:
    wait_for(lambda: bed.node.api_get(f"/api/v1/namespaces/{bed.namespace}/pods/holder") is None, 30,
             "the holder pod gone")
    registrations = bed.sample("armnet_agent_device_plugin_registrations_total", result="ok")
    bed.node.restart_kubelet()
    wait_for(lambda: bed.sample("armnet_agent_device_plugin_registrations_total", result="ok") > registrations, 15,
             "the plugin registered with the new kubelet")
    os.write(bed.master, b"after restart\n")
    bed.pod("after-restart")
    pod = bed.wait_pod("after-restart", ("Succeeded", "Failed"))
    assert pod["status"]["phase"] == "Succeeded", pod["status"]
    assert bed.answer_from_the_arm() == b"pong after restart\n"

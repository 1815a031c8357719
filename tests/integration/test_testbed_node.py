"""The test bed's node is a real one: pods run, native sidecars gate the main container
(with a startup probe, or with the ``postStart`` gate the pod launcher uses),
memory-backed volumes are shared, deadlines kill, and logs come through the apiserver.

All pods of this module are created at once (``pods`` fixture) and run side by side
on the node; each test then waits for its own pod, so the module costs about as
long as its slowest pod.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from typing import Any

import pytest
from armnet_launch.pod_spec import serving_gate
from armnet_testbed.images import BASE_IMAGE
from armnet_testbed.kube import ControlPlane
from armnet_testbed.node import Node

pytestmark = pytest.mark.node

SOCKET_DIR = "/run/armnet"
SOCKET = f"{SOCKET_DIR}/server.sock"

# Binds its socket only after 2 s: a main container started before the sidecar's
# startup probe passed would find no socket (it does not retry) and fail the pod.
SERVER = f"""
import os, socket, time
time.sleep(2)
srv = socket.socket(socket.AF_UNIX)
srv.bind({SOCKET!r})
srv.listen(1)
print("listening", flush=True)
while True:
    conn, _ = srv.accept()
    line = conn.makefile().readline().strip()
    conn.sendall(("pong " + line + chr(10)).encode())
    conn.close()
"""
CLIENT = f"""
import socket
c = socket.socket(socket.AF_UNIX)
c.connect({SOCKET!r})
c.sendall(b"ping" + bytes([10]))
print(c.makefile().readline().strip(), flush=True)
"""
SHM_WRITER = """
import mmap, os, time
fd = os.open("/shm/segment", os.O_RDWR | os.O_CREAT, 0o644)
os.ftruncate(fd, 4096)
m = mmap.mmap(fd, 4096)
m[:13] = b"armnet-frames"
m.flush()
os.rename("/shm/segment", "/shm/ready")
time.sleep(3600)
"""
SHM_READER = """
import mmap, os
fs = [line.split()[2] for line in open("/proc/mounts") if line.split()[1] == "/shm"]
m = mmap.mmap(os.open("/shm/ready", os.O_RDONLY), 4096, prot=mmap.PROT_READ)
data = bytes(m[:13]).decode()
print(fs[0], data, flush=True)
raise SystemExit(0 if fs == ["tmpfs"] and data == "armnet-frames" else 1)
"""


def container(name: str, script: str, **extra: Any) -> dict[str, Any]:
    return {"name": name, "image": BASE_IMAGE, "imagePullPolicy": "Never",
            "command": ["python3", "-c", script], **extra}


def probe(*argv: str) -> dict[str, Any]:
    return {"exec": {"command": list(argv)}, "periodSeconds": 1, "failureThreshold": 60}


def sidecar_pod(node: Node) -> dict[str, Any]:
    mount = [{"name": "sock", "mountPath": SOCKET_DIR}]
    return node.pod_yaml(
        "sidecar",
        initContainers=[container("server", SERVER, restartPolicy="Always", volumeMounts=mount,
                                  startupProbe=probe("test", "-S", SOCKET))],
        containers=[container("main", CLIENT, volumeMounts=mount)],
        volumes=[{"name": "sock", "emptyDir": {}}],
    )


def unprobed_sidecar_pod(node: Node) -> dict[str, Any]:
    """The sidecar pod without its startup probe: nothing makes the main container wait."""
    pod = sidecar_pod(node)
    pod["metadata"]["name"] = "unprobed"
    del pod["spec"]["initContainers"][0]["startupProbe"]
    return pod


def gated_sidecar_pod(node: Node) -> dict[str, Any]:
    """The sidecar pod gated as the pod launcher gates the connector: a ``postStart`` hook, no probe."""
    pod = unprobed_sidecar_pod(node)
    pod["metadata"]["name"] = "gated"
    pod["spec"]["initContainers"][0]["lifecycle"] = {"postStart": {"exec": {"command": serving_gate(SOCKET, 60)}}}
    return pod


def shared_memory_pod(node: Node) -> dict[str, Any]:
    mount = [{"name": "shm", "mountPath": "/shm"}]
    return node.pod_yaml(
        "shm",
        initContainers=[container("writer", SHM_WRITER, restartPolicy="Always",
                                  volumeMounts=mount, startupProbe=probe("test", "-f", "/shm/ready"))],
        containers=[container("reader", SHM_READER, volumeMounts=mount)],
        volumes=[{"name": "shm", "emptyDir": {"medium": "Memory", "sizeLimit": "8Mi"}}],
    )


def overdue_pod(node: Node) -> dict[str, Any]:
    return node.pod_yaml("overdue", activeDeadlineSeconds=3,
                         containers=[container("main", "import time; time.sleep(3600)")])


@pytest.fixture(scope="module")
def pods(k8s_node: Node, k8s: ControlPlane) -> Iterator[str]:
    """Creates every pod of this module at once; yields their namespace."""
    namespace = k8s.create_namespace("node")
    manifests = [sidecar_pod(k8s_node), unprobed_sidecar_pod(k8s_node), gated_sidecar_pod(k8s_node),
                 shared_memory_pod(k8s_node), overdue_pod(k8s_node)]
    k8s.kubectl("apply", "-n", namespace, "-f", "-",
                input=json.dumps({"apiVersion": "v1", "kind": "List", "items": manifests}))
    try:
        yield namespace
    finally:
        k8s.kubectl("delete", "pods", "--all", "-n", namespace, "--grace-period=1",
                    "--wait=false", check=False)
        k8s.delete_namespace(namespace)


def exit_code(pod: dict[str, Any], name: str) -> int | None:
    for status in pod["status"].get("containerStatuses", []):
        if status["name"] == name:
            terminated = status["state"].get("terminated") or {}
            return terminated.get("exitCode")
    return None


def test_node_registers_and_is_ready(k8s_node: Node) -> None:
    node = k8s_node.node_object()

    assert node is not None
    ready = [c for c in node["status"]["conditions"] if c["type"] == "Ready"]
    assert ready[0]["status"] == "True", ready
    assert {"type": "InternalIP", "address": k8s_node.node_ip} in node["status"]["addresses"]


def test_main_container_starts_only_after_the_native_sidecar_serves_its_socket(
        k8s_node: Node, pods: str) -> None:
    pod = k8s_node.wait_for_pod(pods, "sidecar")

    assert pod["status"]["phase"] == "Succeeded", pod["status"]
    assert exit_code(pod, "main") == 0


def test_main_container_starts_only_after_the_native_sidecars_post_start_gate_saw_its_socket(
        k8s_node: Node, pods: str) -> None:
    pod = k8s_node.wait_for_pod(pods, "gated")

    assert pod["status"]["phase"] == "Succeeded", pod["status"]
    assert exit_code(pod, "main") == 0


def test_without_a_startup_probe_the_main_container_does_not_wait_for_the_sidecar(
        k8s_node: Node, pods: str) -> None:
    pod = k8s_node.wait_for_pod(pods, "unprobed")

    assert pod["status"]["phase"] == "Failed"
    assert exit_code(pod, "main") == 1


def test_memory_emptydir_is_a_tmpfs_shared_by_two_containers(k8s_node: Node, pods: str) -> None:
    pod = k8s_node.wait_for_pod(pods, "shm")

    assert pod["status"]["phase"] == "Succeeded", pod["status"]
    assert exit_code(pod, "reader") == 0


def test_active_deadline_kills_a_pod_that_outlives_its_window(k8s_node: Node, pods: str) -> None:
    pod = k8s_node.wait_for_pod(pods, "overdue", timeout=60)

    assert pod["status"]["phase"] == "Failed"
    assert pod["status"]["reason"] == "DeadlineExceeded"


def test_kubectl_logs_reads_container_output_through_the_apiserver(
        k8s_node: Node, k8s: ControlPlane, pods: str) -> None:
    k8s_node.wait_for_pod(pods, "sidecar")

    main = k8s.kubectl("logs", "-n", pods, "sidecar", "-c", "main").stdout
    server = k8s.kubectl("logs", "-n", pods, "sidecar", "-c", "server").stdout

    assert main.strip() == "pong ping"
    assert server.strip() == "listening"

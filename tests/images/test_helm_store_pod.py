"""`helm install` of the chart's bundled object store alone: its pod runs on the test-bed node's kubelet.

What runs: the test bed's apiserver and node (containerd + kubelet), kube-scheduler and
kube-controller-manager with the StatefulSet, PersistentVolume-binder and node-lifecycle controllers, and a
hostPath PersistentVolume the store's claim binds to. The image is SeaweedFS's `weed` as the
test bed built it, on the test bed's Debian base (registries cannot be reached here): the same
layout as SeaweedFS's own image for what the pod runs (`weed` and a POSIX shell on the PATH).

Test-bed concessions, both outside the pod's own behaviour: the pod network is a bridge with no
address on the host (testbed/armnet_testbed/node.py), so the kubelet's HTTP probes cannot reach
the pod; a helm post-renderer (tests/support/drop_probes.py) takes the probes out, and the test
reaches the pod from inside its own network namespace (one the test bed's CNI made), as another
pod on its network would.

Checked there: the init container wrote the identities from the Secrets, the store made the
bucket, the agent's keys write and a tenant's keys read only its namespace, the master, volume
and filer ports are not open on the pod's address (only on its loopback) while S3 is, and a
deleted pod comes back with the bucket and the objects on its volume.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml
from armnet_testbed.controllers import WorkloadControllers
from armnet_testbed.images import BASE_IMAGE
from armnet_testbed.kube import ControlPlane
from armnet_testbed.node import NETNS_DIR, Node
from armnet_testbed.objstore import weed_binary
from armnet_testbed.plugin import Podman

from tests.support.helm import CHART, helm_binary, helm_on
from tests.support.helm_store import BUCKET, KEYS
from tests.support.waiting import wait_for

pytestmark = [pytest.mark.node, pytest.mark.container, pytest.mark.timeout(900)]

STORE_IMAGE = "localhost/armnet-seaweedfs:it"
#: The last probe's error output (a store that answers wrongly, not slowly, says so in the timeout's message).
LAST_PROBE_ERROR: list[str] = []
STORAGE_CLASS = "armnet-store-it"
DROP_PROBES = Path(__file__).resolve().parents[1] / "support" / "drop_probes.py"
#: What runs in the pod's network namespace: the product's S3 client settings, plain boto3 and sockets.
PROBE = r"""
import json, socket, sys
import boto3
from botocore.config import Config
from botocore.exceptions import ClientError
ip, keys, bucket, key = sys.argv[1], json.loads(sys.argv[2]), sys.argv[3], sys.argv[4]
def s3(secret):
    k = keys[secret]
    return boto3.client("s3", endpoint_url=f"http://{ip}:8333", region_name="us-east-1",
                        aws_access_key_id=k["accessKeyId"], aws_secret_access_key=k["secretAccessKey"],
                        config=Config(s3={"addressing_style": "path"}, retries={"max_attempts": 1},
                                      request_checksum_calculation="when_required",
                                      response_checksum_validation="when_required"))
def denied(call, **kw):
    try:
        call(**kw)
    except ClientError as e:
        return e.response["Error"]["Code"] in ("AccessDenied", "403")
    return False
def open_port(host, port):
    try:
        socket.create_connection((host, port), timeout=2).close()
        return True
    except OSError:
        return False
agent, tenant = s3("agent-keys"), s3("team-a-outputs")
out = {"ports_on_pod_ip": {p: open_port(ip, p) for p in (8333, 18333, 8888, 9333, 9340, 18888, 19333, 19340)},
       "filer_on_loopback": open_port("127.0.0.1", 8888)}
if sys.argv[5] == "write":
    agent.put_object(Bucket=bucket, Key=key, Body=b"episode")
out["read_back"] = agent.get_object(Bucket=bucket, Key=key)["Body"].read().decode()
out["tenant_reads_own"] = tenant.get_object(Bucket=bucket, Key=key)["Body"].read().decode()
out["tenant_writes"] = not denied(tenant.put_object, Bucket=bucket, Key=key + ".forged", Body=b"x")
out["agent_makes_buckets"] = not denied(agent.create_bucket, Bucket="another-bucket")
print(json.dumps(out))
"""


def store_image(podman: Podman) -> str:
    """SeaweedFS's `weed` (the test bed's build) on the test bed's Debian base, as the chart's store image."""
    context = Path(tempfile.mkdtemp(prefix="armnet-store-image-"))
    try:
        shutil.copy(weed_binary(), context / "weed")
        (context / "Containerfile").write_text("ARG BASE\nFROM ${BASE}\nCOPY weed /usr/bin/weed\n")
        podman.client.images.build(path=str(context), tag=STORE_IMAGE, rm=True, dockerfile="Containerfile",
                                   buildargs={"BASE": BASE_IMAGE}, network_mode="none")
    finally:
        shutil.rmtree(context, ignore_errors=True)
    return STORE_IMAGE


def apply(k8s: ControlPlane, obj: dict[str, Any]) -> None:
    k8s.kubectl("apply", "-f", "-", input=yaml.safe_dump(obj))


def pod_of(k8s: ControlPlane, namespace: str) -> dict[str, Any] | None:
    listed = k8s.kubectl("get", "pods", "-n", namespace, "-l", "app.kubernetes.io/component=store", "-o", "json",
                         check=False)
    items = json.loads(listed.stdout)["items"] if listed.returncode == 0 else []
    return items[0] if items else None


def running(pod: dict[str, Any] | None) -> str | None:
    """The pod's IP once both its containers run, else None."""
    status = (pod or {}).get("status") or {}
    states = [c.get("state", {}) for c in status.get("containerStatuses", [])]
    if len(states) == 2 and all("running" in s for s in states) and status.get("podIP"):
        return str(status["podIP"])
    return None


def netns_of(ip: str) -> Path:
    """The network namespace (made by the test bed's CNI) that holds ``ip``."""
    for netns in sorted(NETNS_DIR.glob("cni-*")):
        shown = subprocess.run(["ip", "netns", "exec", netns.name, "ip", "-4", "-o", "addr"], capture_output=True,
                               text=True, check=False)
        if f" {ip}/" in shown.stdout:
            return netns
    raise AssertionError(f"no network namespace of the test bed holds {ip}")


def probe(ip: str, key: str, write: bool) -> dict[str, Any] | None:
    """``PROBE``'s answers from inside the pod's network namespace; None while the store does not answer yet."""
    result = subprocess.run(
        ["ip", "netns", "exec", netns_of(ip).name, sys.executable, "-c", PROBE, ip, json.dumps(KEYS), BUCKET, key,
         "write" if write else "read"], capture_output=True, text=True, timeout=60, check=False,
        env={**os.environ, "AWS_EC2_METADATA_DISABLED": "true"})
    if result.returncode != 0:
        LAST_PROBE_ERROR[:] = [result.stderr[-2000:]]
        return None
    answers: dict[str, Any] = json.loads(result.stdout.strip().splitlines()[-1])
    return answers


@pytest.fixture(scope="module")
def store(k8s: ControlPlane, k8s_node: Node, podman: Podman) -> Iterator[dict[str, Any]]:
    k8s_node.import_images(store_image(podman))
    release = f"st-{uuid.uuid4().hex[:6]}"
    claim = f"data-{release}-armnet-store-0"  # the StatefulSet's volumeClaimTemplate "data", its pod 0
    with contextlib.ExitStack() as cleanup:  # every step undone, in reverse, whichever one fails
        namespace = k8s.create_namespace("armnet-store")
        cleanup.callback(k8s.delete_namespace, namespace)
        volume = Path(tempfile.mkdtemp(prefix="armnet-store-pv-"))
        cleanup.callback(shutil.rmtree, volume, ignore_errors=True)
        volume.chmod(0o777)  # the store runs as uid 1000; a hostPath volume gets no fsGroup
        # The node-lifecycle controller lifts the taint a node is registered with once it is Ready.
        controllers = WorkloadControllers(plane=k8s, controllers=(
            "statefulset-controller", "persistentvolume-binder-controller", "node-lifecycle-controller")).start()
        cleanup.callback(controllers.stop)
        for secret, keys in KEYS.items():
            k8s.kubectl("create", "secret", "generic", secret, "-n", namespace,
                        f"--from-literal=accessKeyId={keys['accessKeyId']}",
                        f"--from-literal=secretAccessKey={keys['secretAccessKey']}")
        cleanup.callback(forget_volume, k8s, namespace, claim, f"{release}-data")
        apply(k8s, {"apiVersion": "v1", "kind": "PersistentVolume", "metadata": {"name": f"{release}-data"},
                    "spec": {"capacity": {"storage": "1Gi"}, "accessModes": ["ReadWriteOnce"],
                             "storageClassName": STORAGE_CLASS, "persistentVolumeReclaimPolicy": "Retain",
                             "hostPath": {"path": str(volume), "type": "Directory"}}})
        values = {
            "crds": {"install": False}, "operator": {"enabled": False}, "agent": {"enabled": False},
            "admissionWebhook": {"enabled": False},
            "artifacts": {"bucket": BUCKET, "credentialsSecret": "agent-keys",
                          "operatorCredentialsSecret": "operator-keys", "fmsCredentialsSecret": "fms-keys",
                          "deploy": {"enabled": True, "storageClassName": STORAGE_CLASS, "storageSize": "1Gi",
                                     "image": {"repository": STORE_IMAGE.rsplit(":", 1)[0], "tag": "it",
                                               "pullPolicy": "Never"},
                                     "tenantReaders": [
                                         {"namespace": "team-a", "credentialsSecret": "team-a-outputs"},
                                         {"namespace": "team-b", "credentialsSecret": "team-b-outputs"}]}},
        }
        # Helm runs a post-renderer as a program: this interpreter (it has PyYAML), on the module.
        renderer = volume.parent / f"{release}-drop-probes"
        cleanup.callback(renderer.unlink, missing_ok=True)
        renderer.write_text(f"#!/bin/sh\nexec {sys.executable} {DROP_PROBES}\n")
        renderer.chmod(0o755)
        cleanup.callback(subprocess.run, [
            str(helm_binary()), "uninstall", release, "-n", namespace, "--wait", "--timeout", "60s",
            f"--kubeconfig={k8s.kubeconfig}"], capture_output=True, timeout=120, check=False)
        helm_on(k8s, "install", release, str(CHART), "-n", namespace, "--post-renderer", str(renderer),
                values=values)
        yield {"k8s": k8s, "namespace": namespace, "release": release, "controllers": controllers}


def forget_volume(k8s: ControlPlane, namespace: str, claim: str, volume: str) -> None:
    """The store's pods, claim and volume gone, whatever protection finalizers the apiserver put on them
    (no controller here takes those off)."""
    k8s.kubectl("delete", "pods", "--all", "-n", namespace, "--grace-period=1", "--wait=false", check=False)
    for kind, name, scope in (("pvc", claim, ["-n", namespace]), ("pv", volume, [])):
        k8s.kubectl("delete", kind, name, *scope, "--wait=false", "--ignore-not-found", check=False)
        k8s.kubectl("patch", kind, name, *scope, "--type=merge", "-p", '{"metadata":{"finalizers":null}}',
                    check=False)


def diagnose(state: dict[str, Any]) -> str:
    k8s, namespace = state["k8s"], state["namespace"]
    parts = [state["controllers"].log_tail()]
    pod = pod_of(k8s, namespace)
    parts.append(json.dumps((pod or {}).get("status"))[:3000])
    if pod is not None:
        for container in ("s3-config", "store", "s3"):
            logs = k8s.kubectl("logs", "-n", namespace, pod["metadata"]["name"], "-c", container, "--tail=30",
                               check=False)
            parts.append(f"--- {container}:\n{logs.stdout}{logs.stderr}")
    parts.append(k8s.kubectl("get", "events", "-n", namespace, check=False).stdout[-3000:])
    parts.append(f"--- the last probe from the pod's network:\n{''.join(LAST_PROBE_ERROR)}")
    return "\n".join(parts)


def test_the_charts_store_pod_serves_s3_with_each_secrets_keys_and_keeps_its_other_ports_inside(
        store: dict[str, Any]) -> None:
    k8s, namespace = store["k8s"], store["namespace"]
    ip = wait_for(lambda: running(pod_of(k8s, namespace)), 240, "the store pod running", 1.0, lambda: diagnose(store))
    key = "team-a/0f2b7c1e-8d4a-4f3e-9b6a-1c2d3e4f5a6b/files/data/episode.parquet"
    seen = wait_for(lambda: probe(ip, key, write=True), 120, "the store answering S3 on the pod's address", 1.0,
                    lambda: diagnose(store))

    # S3 and its gRPC (whose admin calls answer local peers only) on the pod's address; nothing of the store.
    assert seen["ports_on_pod_ip"] == {"8333": True, "18333": True, "8888": False, "9333": False, "9340": False,
                                       "18888": False, "19333": False, "19340": False}, seen
    assert seen["filer_on_loopback"] is True  # inside the pod, where only its own containers reach it
    assert (seen["read_back"], seen["tenant_reads_own"]) == ("episode", "episode")
    assert (seen["tenant_writes"], seen["agent_makes_buckets"]) == (False, False)
    init = k8s.kubectl("logs", "-n", namespace, pod_of(k8s, namespace)["metadata"]["name"],  # type: ignore[index]
                       "-c", "s3-config").stdout
    assert "5 identities written" in init


def test_a_deleted_store_pod_comes_back_with_its_bucket_and_objects(store: dict[str, Any]) -> None:
    k8s, namespace = store["k8s"], store["namespace"]
    key = "team-a/5a4f3e2d-1c6b-4a9f-8e3d-0f2b7c1e8d4a/files/meta/info.json"
    first = wait_for(lambda: running(pod_of(k8s, namespace)), 240, "the store pod running", 1.0,
                     lambda: diagnose(store))
    wait_for(lambda: probe(first, key, write=True), 120, "the store taking an object", 1.0, lambda: diagnose(store))
    before = pod_of(k8s, namespace)
    assert before is not None
    k8s.kubectl("delete", "pod", "-n", namespace, before["metadata"]["name"], "--grace-period=5")

    def recreated() -> str | None:
        pod = pod_of(k8s, namespace)
        return running(pod) if pod and pod["metadata"]["uid"] != before["metadata"]["uid"] else None

    ip = wait_for(recreated, 180, "the store pod recreated", 1.0, lambda: diagnose(store))
    seen = wait_for(lambda: probe(ip, key, write=False), 120, "the recreated store answering", 1.0,
                    lambda: diagnose(store))
    assert seen["read_back"] == "episode"

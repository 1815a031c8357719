"""``armnet dev up`` gives what docs/helm.md's install on the test bed needs, with nothing
started by hand: a control plane, a Ready node, kube-controller-manager and
kube-scheduler (a Deployment makes a pod that is scheduled and runs), the kubelet's
root dir for ``agent.kubeletRootDir``, ``NATS_URL`` and the object store's settings. Ctrl-C stops it all.

The real command in its own process; its printed lines are what a user pastes.
"""

from __future__ import annotations

import json
import os
import queue
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from armnet_testbed.images import BASE_IMAGE
from botocore.exceptions import ClientError

pytestmark = [pytest.mark.node, pytest.mark.integration, pytest.mark.timeout(600)]

#: A warm start is ~10 s (control plane, node, controllers); this test runs before its session
#: takes the host's node lock (scripts/test.sh), so it never waits for another node.
UP_WITHIN_S = 240.0


@pytest.fixture(scope="module")
def dev_up() -> Iterator[tuple[subprocess.Popen[str], list[str]]]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "armnet_cli.main", "dev", "up", "--no-podman"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True,
    )
    assert proc.stdout is not None
    lines: queue.Queue[str | None] = queue.Queue()

    def read() -> None:  # a thread: a buffered reader and select() do not mix
        assert proc.stdout is not None
        for line in proc.stdout:
            lines.put(line.rstrip("\n"))
        lines.put(None)

    threading.Thread(target=read, daemon=True).start()
    seen: list[str] = []
    deadline = time.monotonic() + UP_WITHIN_S
    up = False
    while not up and time.monotonic() < deadline:
        try:
            line = lines.get(timeout=1.0)
        except queue.Empty:
            continue
        if line is None:
            break  # it ended
        seen.append(line)
        up = line.startswith("# Ctrl-C stops everything")
    if not up:
        os.killpg(proc.pid, signal.SIGINT)
        proc.wait(timeout=120)
        pytest.fail(f"armnet dev up was not up within {UP_WITHIN_S:.0f} s:\n" + "\n".join(seen[-40:]))
    try:
        yield proc, seen
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout=120)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()


def printed(lines: list[str], pattern: str) -> str:
    for line in lines:
        found = re.search(pattern, line)
        if found:
            return found.group(1)
    raise AssertionError(f"no line matches {pattern!r}:\n" + "\n".join(lines))


def kubectl(lines: list[str], *args: str, stdin: str | None = None) -> str:
    env = {**os.environ, "KUBECONFIG": printed(lines, r"^export KUBECONFIG=(\S+)")}
    tools = printed(lines, r"^export PATH=([^:\s]+):")
    done = subprocess.run([str(Path(tools) / "kubectl"), *args], input=stdin, capture_output=True,
                          text=True, env=env, timeout=60, check=False)
    assert done.returncode == 0, done.stderr
    return done.stdout


def test_dev_up_prints_the_nats_url_and_the_kubelet_root_dir(dev_up) -> None:
    _proc, lines = dev_up
    assert printed(lines, r"^export NATS_URL=(nats://127\.0\.0\.1:\d+)$")
    root = Path(printed(lines, r"agent\.kubeletRootDir\): (\S+)$"))
    assert (root / "pods").is_dir()  # the kubelet keeps its pods there: the agent mounts <root>/pods


def test_dev_up_starts_an_object_store_with_a_bucket_for_job_outputs(dev_up) -> None:
    import boto3
    from botocore.config import Config

    _proc, lines = dev_up
    endpoint = printed(lines, r"^export ARMNET_ARTIFACTS_ENDPOINT=(http://127\.0\.0\.1:\d+)$")
    agent_line = next(line for line in lines if line.startswith("# object store for job outputs"))
    settings = dict(item.split("=", 1) for item in agent_line.split("start the agent with ", 1)[1].split())
    assert settings["ARMNET_ARTIFACTS_ENDPOINT"] == endpoint
    s3 = boto3.session.Session().client(
        "s3", endpoint_url=endpoint, region_name="us-east-1", aws_access_key_id=settings["ARMNET_ARTIFACTS_ACCESS_KEY_ID"],
        aws_secret_access_key=settings["ARMNET_ARTIFACTS_SECRET_ACCESS_KEY"],
        config=Config(s3={"addressing_style": "path"}, request_checksum_calculation="when_required",
                      response_checksum_validation="when_required"))
    bucket = settings["ARMNET_ARTIFACTS_BUCKET"]
    s3.put_object(Bucket=bucket, Key="team-a/some-uid/manifest.json", Body=b"{}")
    assert s3.get_object(Bucket=bucket, Key="team-a/some-uid/manifest.json")["Body"].read() == b"{}"

    # Each tenant's printed keys read its own namespace's outputs, not another's.
    tenant_line = next(line for line in lines if line.startswith("# tenant tenant-a: the outputs of"))
    keys = dict(item.split("=", 1) for item in tenant_line.split() if item.startswith("AWS_"))
    tenant = boto3.session.Session().client(
        "s3", endpoint_url=endpoint, region_name="us-east-1", aws_access_key_id=keys["AWS_ACCESS_KEY_ID"],
        aws_secret_access_key=keys["AWS_SECRET_ACCESS_KEY"],
        config=Config(s3={"addressing_style": "path"}, request_checksum_calculation="when_required",
                      response_checksum_validation="when_required"))
    for namespace in ("tenant-a", "tenant-b"):
        s3.put_object(Bucket=bucket, Key=f"{namespace}/uid-1/manifest.json", Body=namespace.encode())
    assert tenant.get_object(Bucket=bucket, Key="tenant-a/uid-1/manifest.json")["Body"].read() == b"tenant-a"
    with pytest.raises(ClientError, match="AccessDenied"):
        tenant.get_object(Bucket=bucket, Key="tenant-b/uid-1/manifest.json")


def test_a_deployment_on_dev_up_makes_a_pod_that_runs_on_its_node(dev_up) -> None:
    _proc, lines = dev_up
    assert any("kube-controller-manager and kube-scheduler are running" in line for line in lines)
    deployment = {
        "apiVersion": "apps/v1", "kind": "Deployment",
        "metadata": {"name": "sleeper", "namespace": "default"},
        "spec": {"replicas": 1, "selector": {"matchLabels": {"app": "sleeper"}}, "template": {
            "metadata": {"labels": {"app": "sleeper"}},
            "spec": {"dnsPolicy": "Default", "containers": [{
                "name": "sleep", "image": BASE_IMAGE, "imagePullPolicy": "Never",
                "command": ["sleep", "3600"]}]}}},
    }
    kubectl(lines, "apply", "-f", "-", stdin=json.dumps(deployment))
    deadline = time.monotonic() + 180
    pods: list[dict[str, object]] = []
    while time.monotonic() < deadline:
        pods = json.loads(kubectl(lines, "get", "pods", "-n", "default", "-l", "app=sleeper", "-o", "json"))["items"]
        if any(p.get("status", {}).get("phase") == "Running" for p in pods):  # type: ignore[union-attr]
            break
        time.sleep(1)
    assert any(p.get("status", {}).get("phase") == "Running" for p in pods), pods  # type: ignore[union-attr]
    kubectl(lines, "delete", "deployment", "sleeper", "-n", "default", "--wait=false")


def test_ctrl_c_stops_dev_up(dev_up) -> None:
    proc, _lines = dev_up
    proc.send_signal(signal.SIGINT)
    assert proc.wait(timeout=120) == 0

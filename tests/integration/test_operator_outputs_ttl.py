"""`armnet operator` removes a finished job's stored outputs with the job at its TTL, on a real store.

A real API server, the operator as a process given the store the chart gives it (the
agent's variables), SeaweedFS's S3 gateway. The node agent's part (the upload and
``status.artifacts``) is written here as it writes it: this is about what the operator does.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
import urllib.request
import uuid
from datetime import UTC, datetime
from typing import Any

import pytest
import yaml
from armnet_core.api import KEEP_ARTIFACTS_ANNOTATION
from armnet_core.times import kube_time
from armnet_testbed.objstore import SeaweedS3
from armnet_testbed.procs import free_port, wait_until

from tests.support.processes import stop_process

pytestmark = pytest.mark.integration


def a_stored_job(k8s: Any, namespace: str, bucket: str, client: Any, name: str, **annotations: str) -> str:
    """A finished RobotJob with a TTL of 1 s whose outputs the agent stored; returns its prefix."""
    k8s.kubectl("apply", "-n", namespace, "-f", "-", input=yaml.safe_dump({
        "apiVersion": "armnet.io/v1alpha1", "kind": "RobotJob",
        "metadata": {"name": name, "annotations": annotations},
        "spec": {"image": "localhost/armnet-test:dev", "embodiment": "test/outputs", "ttlSecondsAfterFinished": 1}}))
    uid = k8s.kubectl("get", "rj", name, "-n", namespace, "-o", "jsonpath={.metadata.uid}").stdout.strip()
    prefix = f"{namespace}/{uid}/"
    for key in ("files/data/chunk-000.parquet", "files/meta/info.json", "manifest.json"):
        client.put_object(Bucket=bucket, Key=prefix + key, Body=b"stored by the agent")
    k8s.kubectl("patch", "rj", name, "-n", namespace, "--subresource=status", "--type=merge", "-p", json.dumps({
        "status": {"phase": "succeeded", "finishedAt": kube_time(datetime.now(UTC)),
                   "artifacts": {"phase": "Uploaded", "location": f"s3://{bucket}/{prefix}", "files": 2}}}))
    return prefix


def test_a_jobs_outputs_go_with_it_at_its_ttl_and_a_kept_jobs_stay(
        k8s: Any, namespace: str, object_store: SeaweedS3) -> None:
    bucket = object_store.create_bucket(f"ttl-{uuid.uuid4().hex[:10]}")
    client = object_store.client()
    port = free_port()
    argv = [sys.executable, "-m", "armnet_cli.main", "operator", "--kubeconfig", str(k8s.kubeconfig),
            "--namespaces", namespace, "--lease-namespace", namespace, "--metrics-port", str(port),
            "--metrics-address", "127.0.0.1", "--reconcile-period", "0.5"]
    env = {**os.environ, "KUBECONFIG": str(k8s.kubeconfig), **object_store.agent_env(bucket)}
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    try:
        removed = a_stored_job(k8s, namespace, bucket, client, "removed")
        kept = a_stored_job(k8s, namespace, bucket, client, "kept", **{KEEP_ARTIFACTS_ANNOTATION: "true"})

        def gone(name: str) -> bool:
            assert proc.poll() is None, proc.stdout.read() if proc.stdout else ""
            return k8s.kubectl("get", "rj", name, "-n", namespace, check=False).returncode != 0

        wait_until(lambda: gone("removed") and gone("kept"), timeout=60, what="both jobs deleted at their TTL")

        def keys(prefix: str) -> list[str]:
            return [item["Key"] for item in client.list_objects_v2(Bucket=bucket, Prefix=prefix).get("Contents", [])]

        assert keys(removed) == []
        assert sorted(keys(kept)) == sorted(f"{kept}{key}" for key in (
            "files/data/chunk-000.parquet", "files/meta/info.json", "manifest.json"))
        deadline = time.monotonic() + 10
        while True:  # the pass updates its metrics a moment after its writes are visible
            metrics = urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=5).read().decode()
            if 'armnet_job_outputs_removed_total{outcome="removed"} 1.0' in metrics or time.monotonic() > deadline:
                break
            time.sleep(0.2)
        assert 'armnet_job_outputs_removed_total{outcome="removed"} 1.0' in metrics
    finally:
        stop_process(proc)


def test_a_store_that_does_not_answer_is_asked_again_only_after_a_growing_wait() -> None:
    """A removal runs inside the reconcile pass: an outage must cost the pass nothing after its first try."""
    from armnet_core.object_store import StoreConfig
    from armnet_operator.errors import StoreError
    from armnet_operator.outputs_store import OutputsStore

    clock = [100.0]
    nothing_there = StoreConfig(bucket="outputs", access_key_id="k", secret_access_key="s",
                                endpoint_url=f"http://127.0.0.1:{free_port()}")
    store = OutputsStore(nothing_there, clock=lambda: clock[0])
    with pytest.raises(StoreError, match="did not remove t/u-1/ in bucket outputs"):
        store.remove("t/u-1/")
    with pytest.raises(StoreError, match="not asked again for 10 s"):
        store.remove("t/u-2/")
    clock[0] += 10
    with pytest.raises(StoreError, match="did not remove t/u-2/"):
        store.remove("t/u-2/")  # asked again, and failed again: the next wait doubles
    with pytest.raises(StoreError, match="not asked again for 20 s"):
        store.remove("t/u-2/")

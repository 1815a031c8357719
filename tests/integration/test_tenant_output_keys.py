"""A tenant's read keys reach its own namespace's job outputs and nothing else, on a real store.

The session's SeaweedFS, with one read-only identity per tenant namespace (``armnet_testbed.objstore.Reader``:
``Read`` on ``<bucket>/<namespace>/*``, as docs/outputs.md tells a cluster's operator to grant),
outputs stored by the node agent's own upload queue, read back as a tenant does with
``armnet artifacts`` and with a plain S3 client.
"""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from armnet_cli.main import main as armnet
from armnet_node.artifacts import ObjectStore, StoreConfig
from armnet_node.kube import AgentKube
from armnet_node.metrics import AgentMetrics
from armnet_node.plan import HostPaths
from armnet_node.uploads import TrackedJob, UploadQueue
from armnet_testbed.objstore import SeaweedS3
from armnet_testbed.plugin import TENANT_KEYS_BUCKET, TENANT_KEYS_NAMESPACES
from botocore.exceptions import ClientError

from tests.support.fms_objects import a_job, apply, patch_status

pytestmark = pytest.mark.integration

BUCKET = TENANT_KEYS_BUCKET
FILES = {"data/episode_000000.parquet": b"\x01" * 2000, "meta/info.json": b'{"fps": 30}'}


@pytest.fixture(scope="module")
def tenants(k8s: Any) -> Iterator[list[str]]:
    """The two namespaces the session's store has read keys for (``armnet_testbed.plugin``)."""
    from kubernetes import client as kclient

    core = kclient.CoreV1Api(k8s.api_client())
    for namespace in TENANT_KEYS_NAMESPACES:
        core.create_namespace({"metadata": {"name": namespace}})
    yield list(TENANT_KEYS_NAMESPACES)
    for namespace in TENANT_KEYS_NAMESPACES:
        k8s.delete_namespace(namespace)


@pytest.fixture(scope="module")
def store(object_store: SeaweedS3, tenants: list[str]) -> SeaweedS3:
    object_store.create_bucket(BUCKET)
    return object_store


def stored_job(k8s: Any, namespace: str, store: SeaweedS3, tmp_path: Path) -> tuple[str, str]:
    """A succeeded job of ``namespace`` whose output the agent's queue stored; (job name, uid)."""
    agent_store = ObjectStore(StoreConfig(bucket=BUCKET, access_key_id=store.access_key,
                                          secret_access_key=store.secret_key, endpoint_url=store.endpoint))
    meta = apply(k8s, a_job(f"rec-{uuid.uuid4().hex[:6]}", namespace))["metadata"]
    job = TrackedJob(namespace, meta["name"], meta["uid"])
    paths = HostPaths(tmp_path / f"agent-{namespace}")
    queue = UploadQueue(agent_store, paths, AgentKube(k8s.api_client()), AgentMetrics())
    queue.track(job)
    for name, data in FILES.items():
        (paths.output_dir(job.uid) / name).parent.mkdir(parents=True, exist_ok=True)
        (paths.output_dir(job.uid) / name).write_bytes(data)
    patch_status(k8s, "job", job.name, {"phase": "succeeded"}, namespace)
    queue.ready(job.uid)
    queue.process_ready()
    return job.name, job.uid


def as_tenant(monkeypatch: pytest.MonkeyPatch, store: SeaweedS3, namespace: str) -> None:
    for key, value in {**store.readers[namespace].env(), "ARMNET_ARTIFACTS_ENDPOINT": store.endpoint}.items():
        monkeypatch.setenv(key, value)


def denied(call: Any) -> str:
    with pytest.raises(ClientError) as caught:
        call()
    return str(caught.value.response["Error"]["Code"])


def test_a_tenant_downloads_its_own_jobs_outputs_and_is_refused_another_tenants(
    k8s: Any, tenants: list[str], store: SeaweedS3, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    own, other = tenants
    own_job, _ = stored_job(k8s, own, store, tmp_path)
    other_job, other_uid = stored_job(k8s, other, store, tmp_path)
    as_tenant(monkeypatch, store, own)
    where = ["--kubeconfig", str(k8s.kubeconfig)]

    out = tmp_path / "own"
    assert armnet(["artifacts", own_job, "--download", str(out), "-n", own, *where]) == 0
    assert {str(p.relative_to(out)): p.read_bytes() for p in out.rglob("*") if p.is_file()} == FILES
    capsys.readouterr()

    # The other tenant's job: its status says where, the store refuses these keys.
    assert armnet(["artifacts", other_job, "--files", "-n", other, *where]) == 1
    assert "(AccessDenied): give your read credentials" in capsys.readouterr().err

    s3 = store.client(own)
    assert denied(lambda: s3.get_object(Bucket=BUCKET, Key=f"{other}/{other_uid}/manifest.json")) == "AccessDenied"
    assert denied(lambda: s3.list_objects_v2(Bucket=BUCKET, Prefix=f"{own}/")) == "AccessDenied"
    assert denied(lambda: s3.put_object(Bucket=BUCKET, Key=f"{own}/planted.txt", Body=b"x")) == "AccessDenied"
    assert denied(lambda: s3.delete_object(Bucket=BUCKET, Key=f"{other}/{other_uid}/manifest.json")) == "AccessDenied"
    assert denied(lambda: s3.delete_object(Bucket=BUCKET, Key=f"{own}/planted.txt")) == "AccessDenied"
    # What the other tenant's keys read is its own, and the objects are all still there.
    assert store.client(other).get_object(Bucket=BUCKET, Key=f"{other}/{other_uid}/manifest.json")["Body"].read()

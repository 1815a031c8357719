"""``armnet artifacts``: a job's stored output read back from a real store (SeaweedFS) and a real API server.

The output is stored by the node agent's own upload queue (as after a real job), then
the command finds it from the job's ``status.artifacts`` and fetches it with the
user's S3 credentials, checking every file against the manifest's SHA-256.
"""

from __future__ import annotations

import hashlib
import json
import uuid
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

from tests.support.fms_objects import a_job, apply, patch_status

pytestmark = pytest.mark.integration

FILES = {"data/chunk-000/episode_000000.parquet": b"\x01" * 3000, "meta/info.json": b'{"fps": 30}',
         "videos/front/episode_000000.mp4": b"\x00\x00\x00\x18ftypmp42" * 100}


@pytest.fixture
def env(object_store: SeaweedS3, monkeypatch: pytest.MonkeyPatch) -> None:
    """The user's read credentials and the store's URL, as a user would export them."""
    monkeypatch.setenv("AWS_ACCESS_KEY_ID", object_store.access_key)
    monkeypatch.setenv("AWS_SECRET_ACCESS_KEY", object_store.secret_key)
    monkeypatch.setenv("ARMNET_ARTIFACTS_ENDPOINT", object_store.endpoint)


def stored_job(k8s: Any, namespace: str, object_store: SeaweedS3, tmp_path: Path) -> tuple[str, str, str]:
    """A succeeded job whose output the agent's queue stored; (job name, bucket, uid)."""
    bucket = object_store.create_bucket(f"cli-{uuid.uuid4().hex[:10]}")
    store = ObjectStore(StoreConfig(bucket=bucket, access_key_id=object_store.access_key,
                                    secret_access_key=object_store.secret_key, endpoint_url=object_store.endpoint))
    created = apply(k8s, a_job(f"rec-{uuid.uuid4().hex[:6]}", namespace))
    meta = created["metadata"]
    job = TrackedJob(namespace, meta["name"], meta["uid"])
    paths = HostPaths(tmp_path / "agent")
    queue = UploadQueue(store, paths, AgentKube(k8s.api_client()), AgentMetrics())
    queue.track(job)
    for name, data in FILES.items():
        target = paths.output_dir(job.uid) / name
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(data)
    patch_status(k8s, "job", job.name, {"phase": "succeeded"}, namespace)
    queue.ready(job.uid)
    queue.process_ready()
    return job.name, bucket, job.uid


def where(k8s: Any, namespace: str) -> list[str]:
    return ["--kubeconfig", str(k8s.kubeconfig), "-n", namespace]


def test_a_stored_output_is_listed_and_downloaded_whole_with_its_checksums(
    k8s: Any, namespace: str, object_store: SeaweedS3, env: None, tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    name, bucket, uid = stored_job(k8s, namespace, object_store, tmp_path)

    assert armnet(["artifacts", name, *where(k8s, namespace)]) == 0
    summary = capsys.readouterr().out
    assert f"Uploaded: 3 files, {sum(map(len, FILES.values()))} bytes at s3://{bucket}/{namespace}/{uid}/" in summary
    assert armnet(["artifacts", name, "--files", *where(k8s, namespace)]) == 0
    listed = capsys.readouterr().out
    assert f"{hashlib.sha256(FILES['meta/info.json']).hexdigest()}  meta/info.json" in listed

    out = tmp_path / "fetched"
    assert armnet(["artifacts", name, "--download", str(out), *where(k8s, namespace)]) == 0
    assert {str(p.relative_to(out)): p.read_bytes() for p in out.rglob("*") if p.is_file()} == FILES
    assert "downloaded 3 files" in capsys.readouterr().out
    assert armnet(["artifacts", name, "--download", str(out), *where(k8s, namespace)]) == 0  # again: nothing to fetch
    assert "downloaded 0 files to" in (again := capsys.readouterr().out) and "(3 already there)" in again


def test_a_file_changed_in_the_store_after_the_upload_is_not_written(
    k8s: Any, namespace: str, object_store: SeaweedS3, env: None, tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    name, bucket, uid = stored_job(k8s, namespace, object_store, tmp_path)
    key = f"{namespace}/{uid}/files/meta/info.json"
    object_store.client().put_object(Bucket=bucket, Key=key, Body=b'{"fps": 31}')  # same size, other bytes

    out = tmp_path / "fetched"
    assert armnet(["artifacts", name, "--download", str(out), *where(k8s, namespace)]) == 1
    assert "meta/info.json: the stored bytes do not match the manifest's SHA-256" in capsys.readouterr().err
    assert not (out / "meta" / "info.json").exists()
    assert not [p for p in out.rglob(".armnet-*")]  # no partial file left behind


def test_a_manifest_naming_a_path_out_of_the_directory_downloads_nothing_there(
    k8s: Any, namespace: str, object_store: SeaweedS3, env: None, tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    name, bucket, uid = stored_job(k8s, namespace, object_store, tmp_path)
    manifest_key = f"{namespace}/{uid}/manifest.json"
    s3 = object_store.client()
    manifest = json.loads(s3.get_object(Bucket=bucket, Key=manifest_key)["Body"].read())
    manifest["files"][0]["path"] = "../../escaped.txt"
    s3.put_object(Bucket=bucket, Key=manifest_key, Body=json.dumps(manifest).encode())

    out = tmp_path / "deep" / "fetched"
    assert armnet(["artifacts", name, "--download", str(out), *where(k8s, namespace)]) == 1
    assert "not a plain relative path" in capsys.readouterr().err
    assert not (tmp_path / "escaped.txt").exists()


def test_a_job_without_a_stored_output_says_so_and_exits_2(
    k8s: Any, namespace: str, env: None, capsys: pytest.CaptureFixture[str],
) -> None:
    created = apply(k8s, a_job(f"fresh-{uuid.uuid4().hex[:6]}", namespace))
    assert armnet(["artifacts", created["metadata"]["name"], *where(k8s, namespace)]) == 2
    assert "has no stored output yet" in capsys.readouterr().out


def test_wrong_credentials_say_what_to_give(
    k8s: Any, namespace: str, object_store: SeaweedS3, env: None, tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
) -> None:
    name, _, _ = stored_job(k8s, namespace, object_store, tmp_path)
    monkeypatch.setenv("AWS_SECRET_ACCESS_KEY", "not-the-key")
    assert armnet(["artifacts", name, "--files", *where(k8s, namespace)]) == 1
    assert "give your read credentials" in capsys.readouterr().err

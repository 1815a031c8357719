"""A job's output directory in a real S3-compatible store (SeaweedFS): stored whole, resumable, bounded.

Every test uploads to the test bed's SeaweedFS through the agent's own uploader and
reads the bucket back with a plain boto3 client.
"""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import textwrap
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from armnet_node.artifacts import (
    ObjectStore,
    OutputLimits,
    OutputTooLarge,
    StoreConfig,
    StoreMisconfigured,
    upload_output,
)
from armnet_node.artifacts.scan import LINK_OUT, scan_output
from armnet_node.artifacts.upload import upload_scan
from armnet_testbed.objstore import SeaweedS3
from armnet_testbed.procs import wait_until

pytestmark = pytest.mark.integration

NAMESPACE = "team-a"


@pytest.fixture
def store(object_store: SeaweedS3) -> Iterator[ObjectStore]:
    """The agent's store on a fresh bucket of its own."""
    config = StoreConfig(bucket=f"t-{uuid.uuid4().hex[:12]}", access_key_id=object_store.access_key,
                         secret_access_key=object_store.secret_key, endpoint_url=object_store.endpoint)
    s3 = ObjectStore(config)
    s3.ensure_bucket()
    yield s3


def _uid() -> str:
    return str(uuid.uuid4())


def _tree(root: Path, files: dict[str, bytes]) -> Path:
    for name, data in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)
    return root


def _dataset(root: Path, episodes: int = 6) -> dict[str, bytes]:
    files = {f"data/chunk-000/episode_{i:06d}.parquet": os.urandom(1000 + i) for i in range(episodes)}
    files["meta/info.json"] = b'{"fps": 30}'
    files["videos/front/episode_000000.mp4"] = os.urandom(9 * 1024 * 1024)  # over boto3's multipart threshold
    _tree(root, files)
    return files


def test_every_file_is_stored_with_its_checksum_and_the_manifest_lists_them(
    tmp_path: Path, store: ObjectStore, object_store: SeaweedS3,
) -> None:
    files = _dataset(tmp_path)
    uid = _uid()
    report = upload_output(tmp_path, store, NAMESPACE, uid)

    stored = object_store.objects(store.bucket, f"{NAMESPACE}/{uid}/")
    prefix = f"{NAMESPACE}/{uid}/"
    assert {key: data for key, data in stored.items() if key != prefix + "manifest.json"} == {
        f"{prefix}files/{path}": data for path, data in files.items()}
    manifest = json.loads(stored[prefix + "manifest.json"])
    assert manifest["complete"] is True
    assert {f["path"]: f["sha256"] for f in manifest["files"]} == {
        path: hashlib.sha256(data).hexdigest() for path, data in files.items()}
    assert {(a.path, a.bytes, a.sha256) for a in report.artifacts} == {
        (path, len(data), hashlib.sha256(data).hexdigest()) for path, data in files.items()}
    assert report.uploaded_bytes == sum(len(d) for d in files.values())
    head = object_store.client().head_object(Bucket=store.bucket, Key=f"{prefix}files/meta/info.json")
    assert head["Metadata"]["sha256"] == hashlib.sha256(b'{"fps": 30}').hexdigest()


def test_a_second_run_sends_nothing_and_stores_nothing_twice(
    tmp_path: Path, store: ObjectStore, object_store: SeaweedS3,
) -> None:
    files = _dataset(tmp_path)
    uid = _uid()
    upload_output(tmp_path, store, NAMESPACE, uid)
    again = upload_output(tmp_path, store, NAMESPACE, uid)
    assert again.uploaded_bytes == 0
    assert again.already_stored == len(files)
    assert len(object_store.objects(store.bucket, f"{NAMESPACE}/{uid}/")) == len(files) + 1


def test_an_agent_killed_mid_upload_resumes_without_losing_or_repeating_a_file(
    tmp_path: Path, store: ObjectStore, object_store: SeaweedS3,
) -> None:
    out = tmp_path / "out"
    files = {f"episode_{i:03d}.parquet": os.urandom(2000 + i) for i in range(12)}
    _tree(out, files)
    uid = _uid()
    marker = tmp_path / "paused"
    # A real agent process, SIGKILLed after its 5th file is stored (it parks there, so the kill is not a race).
    script = textwrap.dedent(f"""
        import threading
        from pathlib import Path
        from armnet_node.artifacts import ObjectStore, StoreConfig, upload_output

        class Pausing(ObjectStore):
            puts = 0
            def put_file(self, key, body, sha256):
                super().put_file(key, body, sha256)
                Pausing.puts += 1
                if Pausing.puts == 5:
                    Path({str(marker)!r}).write_text("5")
                    threading.Event().wait()

        config = StoreConfig(bucket={store.bucket!r}, access_key_id={object_store.access_key!r},
                             secret_access_key={object_store.secret_key!r}, endpoint_url={object_store.endpoint!r})
        upload_output(Path({str(out)!r}), Pausing(config), {NAMESPACE!r}, {uid!r})
    """)
    agent = subprocess.Popen([sys.executable, "-c", script], env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
    try:
        wait_until(marker.exists, timeout=120, what="the killed agent's 5th stored file",
                   alive=lambda: _alive(agent))
    finally:
        agent.send_signal(signal.SIGKILL)
        agent.wait(timeout=30)
    prefix = f"{NAMESPACE}/{uid}/"
    assert prefix + "manifest.json" not in object_store.objects(store.bucket, prefix)  # an unfinished upload

    report = upload_output(out, store, NAMESPACE, uid)

    assert report.already_stored == 5
    assert report.uploaded_bytes == sum(len(d) for d in list(files.values())[5:])
    stored = object_store.objects(store.bucket, prefix)
    assert len(stored) == len(files) + 1
    assert {key.removeprefix(prefix + "files/"): data for key, data in stored.items()
            if key != prefix + "manifest.json"} == files
    assert len(json.loads(stored[prefix + "manifest.json"])["files"]) == len(files)


def _alive(process: subprocess.Popen[Any]) -> None:
    if process.poll() is not None:
        raise RuntimeError(f"the uploading process exited with {process.returncode} before it paused")


def test_an_object_with_another_checksum_under_the_key_is_replaced(
    tmp_path: Path, store: ObjectStore, object_store: SeaweedS3,
) -> None:
    _tree(tmp_path, {"a.bin": b"the job's bytes"})
    uid = _uid()
    key = f"{NAMESPACE}/{uid}/files/a.bin"
    object_store.client().put_object(Bucket=store.bucket, Key=key, Body=b"other bytes, sam",
                                     Metadata={"sha256": "0" * 64})
    report = upload_output(tmp_path, store, NAMESPACE, uid)
    assert report.already_stored == 0
    assert object_store.objects(store.bucket, key)[key] == b"the job's bytes"


def test_a_file_that_grows_after_the_walk_is_not_stored_and_is_reported(
    tmp_path: Path, store: ObjectStore, object_store: SeaweedS3,
) -> None:
    _tree(tmp_path, {"log.txt": b"line 1\n", "done.txt": b"ok"})
    uid = _uid()
    scan = scan_output(tmp_path, OutputLimits())
    with open(tmp_path / "log.txt", "ab") as log:  # a process still writing after the job ended
        log.write(b"line 2\n")

    report = upload_scan(scan, store, NAMESPACE, uid)

    assert [a.path for a in report.artifacts] == ["done.txt"]
    assert [c.path for c in report.changed] == ["log.txt"]
    assert "size went from 7 to 14 bytes" in report.changed[0].reason
    assert not report.complete
    prefix = f"{NAMESPACE}/{uid}/"
    stored = object_store.objects(store.bucket, prefix)
    assert prefix + "files/log.txt" not in stored
    assert json.loads(stored[prefix + "manifest.json"])["complete"] is False


def test_a_symlink_out_and_a_dot_dot_never_reach_the_store(
    tmp_path: Path, store: ObjectStore, object_store: SeaweedS3,
) -> None:
    secret = tmp_path / "agent-token"
    secret.write_bytes(b"SECRET-TOKEN")
    out = tmp_path / "out"
    _tree(out, {"ok.txt": b"fine", "sub/a..b": b"dots in a name are fine"})
    (out / "token").symlink_to(secret)
    (out / "parent").symlink_to("..")
    uid = _uid()

    report = upload_output(out, store, NAMESPACE, uid)

    stored = object_store.objects(store.bucket, "")  # the whole bucket
    assert all(b"SECRET-TOKEN" not in data for data in stored.values())
    assert all(".." not in key.split("/") for key in stored)
    assert sorted(a.path for a in report.artifacts) == ["ok.txt", "sub/a..b"]
    assert {(r.path, r.reason) for r in report.refused} == {("token", LINK_OUT), ("parent", LINK_OUT)}


def test_ten_thousand_tiny_files_over_the_cap_store_nothing(
    tmp_path: Path, store: ObjectStore, object_store: SeaweedS3,
) -> None:
    for i in range(10_000):
        (tmp_path / f"f{i:05d}").write_bytes(b"x")
    uid = _uid()
    with pytest.raises(OutputTooLarge, match="more than 2000 entries"):
        upload_output(tmp_path, store, NAMESPACE, uid, OutputLimits(max_files=2000))
    assert object_store.objects(store.bucket, f"{NAMESPACE}/{uid}/") == {}


def test_wrong_keys_are_a_clear_misconfiguration(tmp_path: Path, store: ObjectStore, object_store: SeaweedS3) -> None:
    _tree(tmp_path, {"a": b"x"})
    wrong = ObjectStore(StoreConfig(bucket=store.bucket, access_key_id=object_store.access_key,
                                    secret_access_key="not-the-key", endpoint_url=object_store.endpoint),
                        max_attempts=1)
    with pytest.raises(StoreMisconfigured, match="check the agent's bucket and keys"):
        upload_output(tmp_path, wrong, NAMESPACE, _uid())

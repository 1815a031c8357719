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
from armnet_testbed.objstore import SeaweedS3

from tests.support import stored_outputs
from tests.support.fms_objects import a_job, apply

pytestmark = pytest.mark.integration

FILES = {"data/chunk-000/episode_000000.parquet": b"\x01" * 3000, "meta/info.json": b'{"fps": 30}',
         "videos/front/episode_000000.mp4": b"\x00\x00\x00\x18ftypmp42" * 100}


@pytest.fixture
def env(object_store: SeaweedS3, monkeypatch: pytest.MonkeyPatch) -> None:
    """The user's read credentials and the store's URL, as a user would export them."""
    monkeypatch.setenv("AWS_ACCESS_KEY_ID", object_store.access_key)
    monkeypatch.setenv("AWS_SECRET_ACCESS_KEY", object_store.secret_key)
    monkeypatch.setenv("ARMNET_ARTIFACTS_ENDPOINT", object_store.endpoint)


def stored_job(k8s: Any, namespace: str, object_store: SeaweedS3, tmp_path: Path,
               record: Path | None = None) -> tuple[str, str, str]:
    """A succeeded job whose output (``FILES``) the agent's queue stored; (job name, bucket, uid)."""
    return stored_outputs.stored_job(k8s, namespace, object_store, tmp_path, FILES, record=record)


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


def test_armnet_view_plays_the_cell_s_video_of_the_job_in_step_with_its_clock(
    k8s: Any, namespace: str, object_store: SeaweedS3, env: None, nats_server: str, tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    import rerun.dataframe

    first = stored_outputs.a_cell_record_with_a_video(tmp_path / "record", frames=12)
    name, _, _ = stored_job(k8s, namespace, object_store, tmp_path, record=tmp_path / "record")
    out = tmp_path / "out.rrd"

    assert armnet(["view", name, "--cell-video", "--save", str(out), "--nats-url", nats_server,
                   *where(k8s, namespace)]) == 0
    assert "the cell's videos: front" in capsys.readouterr().err

    recording = rerun.dataframe.load_recording(str(out))
    table = recording.view(index="time", contents="/armnet-cell/video/front").select().read_all()
    times = [t.timestamp() for t in table.column("time").to_pylist()]
    assert len(times) == 12 and times[0] == pytest.approx(first, abs=0.05)
    assert times[-1] - times[0] == pytest.approx(1.1, abs=0.01)  # the frames' own spacing, 0.1 s
    static = recording.view(index=None, contents="/armnet-cell/video/front").select().read_all()  # the asset
    blob = next(c for c in static.column_names if c.endswith("AssetVideo:blob"))
    assert bytes(static.column(blob).to_pylist()[0][0]) == (tmp_path / "record" / "videos" / "front.mp4").read_bytes()


def test_armnet_view_of_a_job_whose_output_is_not_stored_says_what_to_wait_for(
    k8s: Any, namespace: str, env: None, nats_server: str, tmp_path: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    created = apply(k8s, a_job(f"fresh-{uuid.uuid4().hex[:6]}", namespace))
    assert armnet(["view", created["metadata"]["name"], "--cell-video", "--save", str(tmp_path / "x.rrd"),
                   "--nats-url", nats_server, *where(k8s, namespace)]) == 1
    assert "the cell's videos come with it once the node agent stored it" in capsys.readouterr().err

"""The FMS cell page's "Video of the last job": ``armnet fms`` (least privilege, the chart's read keys)
against the real apiserver and a real store (SeaweedFS), over outputs the agent's own queue stored."""

from __future__ import annotations

import uuid
from collections.abc import Callable, Iterator
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import httpx
import pytest
from armnet_core.times import kube_time
from armnet_testbed.objstore import SeaweedS3
from armnet_testbed.plugin import FMS_READER, FMS_VIDEO_BUCKET

from tests.support.fms_objects import a_cell, apply, grant_fms
from tests.support.fms_server import TOKEN, FmsServer
from tests.support.stored_outputs import a_cell_record_with_a_video, stored_job
from tests.support.waiting import wait_for

pytestmark = [pytest.mark.integration, pytest.mark.timeout(180)]


@pytest.fixture(scope="module")
def bucket(object_store: SeaweedS3) -> str:
    return str(object_store.create_bucket(FMS_VIDEO_BUCKET))


@pytest.fixture(scope="module")
def fms(k8s: Any, nats_server: str, object_store: SeaweedS3, bucket: str) -> Iterator[FmsServer]:
    """The FMS with least privilege on the apiserver and read-only keys to the whole bucket (the chart's)."""
    user = k8s.user("armnet-fms-video", groups=())
    grant_fms(k8s, "armnet-fms-video")
    server = FmsServer(user.kubeconfig, nats_server, env=object_store.reader_env(FMS_READER))
    yield server
    server.stop()


@pytest.fixture
def http(fms: FmsServer) -> Iterator[httpx.Client]:
    with httpx.Client(base_url=fms.url, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=30) as client:
        yield client


def last_video(http: httpx.Client, cell: str, expect: Callable[[httpx.Response], bool], **params: str) -> httpx.Response:
    """The cell's last-job video once the FMS's list of jobs (read at most every 5 s) has the test's jobs."""
    replies: list[httpx.Response] = []

    def asked() -> bool:
        replies.append(http.get(f"/api/cells/{cell}/last-video.mp4", params=params))
        return expect(replies[-1])

    wait_for(asked, timeout=30, what=f"the FMS's answer for cell {cell} to change", every=0.5)
    return replies[-1]


@pytest.fixture
def cell(k8s: Any) -> str:
    """A new Cell of the test's own."""
    name = f"vid-{uuid.uuid4().hex[:6]}"
    apply(k8s, a_cell(name))
    return name


def ended_on(cell: str, minutes_ago: float) -> dict[str, Any]:
    return {"cellName": cell, "finishedAt": kube_time(datetime.now(UTC) - timedelta(minutes=minutes_ago))}


def test_the_cell_page_streams_the_video_of_the_job_that_ended_last_on_the_cell(
    k8s: Any, namespace: str, object_store: SeaweedS3, bucket: str, http: httpx.Client, tmp_path: Path, cell: str,
) -> None:
    a_cell_record_with_a_video(tmp_path / "older", frames=4)
    a_cell_record_with_a_video(tmp_path / "newer", frames=9, camera="wrist")
    stored_job(k8s, namespace, object_store, tmp_path, {"a.txt": b"a"}, record=tmp_path / "older", bucket=bucket,
               status=ended_on(cell, 30))
    newer, _, _ = stored_job(k8s, namespace, object_store, tmp_path, {}, record=tmp_path / "newer", bucket=bucket,
                             status=ended_on(cell, 5))
    stored_job(k8s, namespace, object_store, tmp_path, {}, record=tmp_path / "newer", bucket=bucket,
               status=ended_on(f"{cell}-other", 1))  # a later job, on another cell

    assert '<meta name="video" content="on">' in http.get(f"/cells/{cell}").text
    reply = last_video(http, cell, lambda r: r.status_code == 200)
    assert reply.headers["content-type"] == "video/mp4" and reply.headers["x-armnet-job"] == f"{namespace}/{newer}"
    assert reply.content == (tmp_path / "newer" / "videos" / "wrist.mp4").read_bytes()
    assert f'filename="{newer}-wrist.mp4"' in reply.headers["content-disposition"]
    missing = http.get(f"/api/cells/{cell}/last-video.mp4", params={"camera": "front"})
    assert missing.status_code == 404 and "used no camera front" in missing.json()["error"]


def test_a_status_naming_another_place_in_the_bucket_is_not_followed(
    k8s: Any, namespace: str, object_store: SeaweedS3, bucket: str, http: httpx.Client, tmp_path: Path, cell: str,
) -> None:
    from tests.support.fms_objects import patch_status

    a_cell_record_with_a_video(tmp_path / "rec", frames=3)
    _, _, victim = stored_job(k8s, namespace, object_store, tmp_path, {}, record=tmp_path / "rec", bucket=bucket,
                              status=ended_on(f"{cell}-victim", 10))
    forger, _, _ = stored_job(k8s, namespace, object_store, tmp_path, {}, bucket=bucket, status=ended_on(cell, 1))
    # The job's status (a tenant cannot write it, but the FMS must not depend on that) points at another job's output.
    patch_status(k8s, "job", forger, {"artifacts": {"phase": "Uploaded", "location": f"s3://{bucket}/{namespace}/{victim}/",
                                                    "manifest": f"s3://{bucket}/{namespace}/{victim}/manifest.json"}},
                 namespace)
    reply = last_video(http, cell, lambda r: "is not where this FMS reads" in r.text)
    assert reply.status_code == 404, reply.text


def test_a_cell_whose_jobs_stored_nothing_says_so(http: httpx.Client, cell: str) -> None:
    reply = http.get(f"/api/cells/{cell}/last-video.mp4")
    assert reply.status_code == 404 and f"no ended job on cell {cell} has its output stored" in reply.json()["error"]


def test_without_an_object_store_the_page_offers_no_video(k8s: Any, nats_server: str) -> None:
    user = k8s.user("armnet-fms-novideo", groups=())
    grant_fms(k8s, "armnet-fms-novideo")
    server = FmsServer(user.kubeconfig, nats_server)
    try:
        with httpx.Client(base_url=server.url, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=30) as client:
            assert '<meta name="video" content="off">' in client.get("/cells/any").text
            reply = client.get("/api/cells/any/last-video.mp4")
            assert reply.status_code == 404 and "reads no object store" in reply.json()["error"]
    finally:
        server.stop()

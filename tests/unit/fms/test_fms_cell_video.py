"""The pure choices behind the cell page's last-job video: which job, which file (fms/cell_video.py)."""

from __future__ import annotations

import json
from typing import Any

from armnet_fms.cell_video import last_stored_job, video_in_manifest


def job(name: str, cell: str, finished: str | None, phase: str = "Uploaded") -> dict[str, Any]:
    return {"metadata": {"name": name, "namespace": "team-a"},
            "status": {"phase": "succeeded", "cellName": cell, "finishedAt": finished,
                       "artifacts": {"phase": phase, "location": f"s3://out/team-a/{name}/",
                                     "manifest": f"s3://out/team-a/{name}/manifest.json"}}}


def test_the_job_that_ended_last_on_the_cell_with_a_stored_output_is_chosen() -> None:
    jobs = [job("old", "c1", "2026-12-01T10:00:00Z"), job("new", "c1", "2026-12-01T11:00:00Z"),
            job("newest-elsewhere", "c2", "2026-12-01T12:00:00Z"),
            job("newer-not-stored", "c1", "2026-12-01T11:30:00Z", phase="Pending"),
            job("running", "c1", None), {"metadata": "garbage", "status": ["not", "a", "status"]}]
    chosen = last_stored_job(jobs, "c1")
    assert chosen is not None and (chosen.name, chosen.location) == ("new", "s3://out/team-a/new/")
    assert last_stored_job(jobs, "c3") is None


def manifest(*entries: dict[str, Any]) -> bytes:
    return json.dumps({"files": list(entries)}).encode()


def test_a_video_is_picked_only_from_the_cell_s_record_under_the_job_s_own_prefix() -> None:
    prefix = "team-a/uid-1/"
    files = manifest(
        {"path": "armnet-cell/videos/wrist.mp4", "key": prefix + "files/armnet-cell/videos/wrist.mp4"},
        {"path": "armnet-cell/videos/front.mp4", "key": prefix + "files/armnet-cell/videos/front.mp4"},
        {"path": "videos/front.mp4", "key": prefix + "files/videos/front.mp4"},  # the job's own, not the cell's
        {"path": "armnet-cell/videos/top.mp4", "key": "team-b/uid-9/files/armnet-cell/videos/top.mp4"},
        {"path": "armnet-cell/videos/up.mp4", "key": prefix + "../../team-b/up.mp4"},
        "not an entry",
    )
    first = video_in_manifest(files, prefix)
    assert first is not None and (first.camera, first.key) == ("front", prefix + "files/armnet-cell/videos/front.mp4")
    wrist = video_in_manifest(files, prefix, "wrist")
    assert wrist is not None and wrist.camera == "wrist"
    assert video_in_manifest(files, prefix, "top") is None  # another tenant's key
    assert video_in_manifest(files, prefix, "up") is None  # a key that climbs out
    assert video_in_manifest(b"not json", prefix) is None and video_in_manifest(b'{"files": 3}', prefix) is None

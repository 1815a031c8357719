"""Ended jobs whose output the node agent's own upload queue stored in a real store (SeaweedFS), for the
tests that read it back (``armnet artifacts``, ``armnet view --cell-video``, the FMS's last-job video)."""

from __future__ import annotations

import shutil
import time
import uuid
from pathlib import Path
from typing import Any

from armnet_node.artifacts import ObjectStore, StoreConfig
from armnet_node.kube import AgentKube
from armnet_node.metrics import AgentMetrics
from armnet_node.plan import HostPaths
from armnet_node.uploads import TrackedJob, UploadQueue
from armnet_testbed.objstore import SeaweedS3

from tests.support.fms_objects import a_job, apply, patch_status


def stored_job(k8s: Any, namespace: str, object_store: SeaweedS3, work: Path, files: dict[str, bytes], *,
               record: Path | None = None, bucket: str | None = None, status: dict[str, Any] | None = None,
               ) -> tuple[str, str, str]:
    """A succeeded job (its status also ``status``) whose output ``files`` and cell ``record`` the agent's
    queue stored in ``bucket`` (default: a new one); (job name, bucket, uid)."""
    bucket = bucket or object_store.create_bucket(f"out-{uuid.uuid4().hex[:10]}")
    store = ObjectStore(StoreConfig(bucket=bucket, access_key_id=object_store.access_key,
                                    secret_access_key=object_store.secret_key, endpoint_url=object_store.endpoint))
    created = apply(k8s, a_job(f"rec-{uuid.uuid4().hex[:6]}", namespace))
    meta = created["metadata"]
    job = TrackedJob(namespace, meta["name"], meta["uid"])
    paths = HostPaths(work / f"agent-{job.uid}")
    queue = UploadQueue(store, paths, AgentKube(k8s.api_client()), AgentMetrics())
    queue.track(job)
    for name, data in files.items():
        target = paths.output_dir(job.uid) / name
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(data)
    if record is not None:
        shutil.copytree(record, paths.record_dir(job.uid))
    patch_status(k8s, "job", job.name, {"phase": "succeeded", **(status or {})}, namespace)
    queue.ready(job.uid)
    queue.process_ready()
    return job.name, bucket, job.uid


def a_cell_record_with_a_video(directory: Path, frames: int, camera: str = "front") -> float:
    """The connector's video of one camera, as it writes it for a job (frames 0.1 s apart); when its first
    frame reached it, on the wall clock."""
    import numpy as np
    from armnet_connector.camera_video import CameraVideo
    from armnet_connector.cell import Counters

    counters = Counters()
    video = CameraVideo(directory, counters, max_fps=0).start()
    tap = video.tap(camera)
    first_wall, first = time.time() - 60, time.monotonic() - 60
    for index in range(frames):
        tap(np.full((48, 64, 3), index * 8, np.uint8), first + index / 10)
        while video._queue.qsize() > 4:  # the queue holds 8: the connector's camera would not wait either,
            time.sleep(0.005)            # but a test that wants every frame waits for room
    video.stop(60)
    assert counters.video_frames_written == frames
    return first_wall

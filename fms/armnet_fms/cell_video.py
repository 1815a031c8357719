"""The cell page's video of the last job: the newest ended job on a cell whose output is stored, and the
cell's own video of it (docs/fms.md, "The last job's video").

The connector keeps a video of each camera a job used in the cell's record of the job, and the
node agent stores it with the job's output (``armnet-cell/videos/<camera>.mp4``: docs/outputs.md).
A cell operator looking into what happened at a cell opens it from the cell page; the FMS reads it
with its own keys (the chart's ``artifacts.*``) and streams it, so no store address or key reaches
the browser.

The choice of job and file is pure (``last_stored_job``, ``video_in_manifest``); ``CellVideos``
does the reads. Nothing in a manifest is trusted beyond picking a key under the job's own prefix.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any

from armnet_core.api import ArtifactsPhase
from armnet_core.cell_record import cell_video_camera
from armnet_core.lenient import read_leniently
from armnet_core.object_store import StoreConfig, s3_client
from armnet_core.output_keys import MANIFEST_NAME, MAX_MANIFEST_BYTES, job_prefix
from armnet_core.resources import Metadata, RobotJobStatus

CHUNK = 1 << 20


@dataclass(frozen=True)
class StoredJob:
    """An ended job on the cell whose output (and the cell's record of it) is stored."""

    namespace: str
    name: str
    uid: str
    finished_at: float
    #: ``s3://bucket/<namespace>/<uid>/``, as the job's status says (checked against the job's own prefix).
    location: str


@dataclass(frozen=True)
class CameraVideo:
    """A camera's video in the stored output: its camera and object key."""

    camera: str
    key: str


@dataclass
class OpenVideo:
    """A video being read from the store: what it is, its size, and its bytes in chunks."""

    job: StoredJob
    camera: str
    #: Its size in bytes, as the store says (None: it did not).
    length: int | None
    chunks: Iterator[bytes]


def last_stored_job(jobs: Iterable[Mapping[str, Any]], cell: str) -> StoredJob | None:
    """The job that ended last on ``cell`` among ``jobs`` whose output is ``Uploaded``, or None."""
    best: StoredJob | None = None
    for job in jobs:
        status = read_leniently(RobotJobStatus, job.get("status") or {})
        if status is None or status.cell_name != cell or status.finished_at is None:
            continue
        stored = status.artifacts
        if stored is None or stored.phase != ArtifactsPhase.UPLOADED or not stored.location or not stored.manifest:
            continue
        meta = read_leniently(Metadata, job.get("metadata")) or Metadata()
        candidate = StoredJob(meta.namespace or "", meta.name, meta.uid or "", status.finished_at.timestamp(),
                              stored.location)
        if best is None or candidate.finished_at > best.finished_at:
            best = candidate
    return best


def video_in_manifest(manifest: bytes, prefix: str, camera: str | None = None) -> CameraVideo | None:
    """The video of ``camera`` (None: the first camera by name) the manifest lists under the job's ``prefix``
    (a non-empty ``<namespace>/<uid>/``: no key elsewhere is taken)."""
    if not prefix.endswith("/") or prefix == "/":
        return None
    try:
        files = json.loads(manifest).get("files")
    except (ValueError, AttributeError):
        return None
    videos = []
    for entry in files if isinstance(files, list) else ():
        if not isinstance(entry, Mapping):
            continue
        path, key = entry.get("path"), entry.get("key")
        name = cell_video_camera(path) if isinstance(path, str) else None
        if name is None or not isinstance(key, str) or not key.startswith(prefix) or ".." in key.split("/"):
            continue
        videos.append(CameraVideo(name, key))
    videos.sort(key=lambda v: v.camera)
    if camera is not None:
        videos = [v for v in videos if v.camera == camera]
    return videos[0] if videos else None


class CellVideos:
    """Reads the last job's video of a cell from the store, with the FMS's keys (blocking: call it in a thread).

    Only the configured bucket, and only below the job's own prefix (``<namespace>/<uid>/``, from the
    job's metadata): a status that names another place is not followed. The RobotJobs are listed at
    most once every ``JOBS_TTL_S`` (the list is cluster-wide; a page reloaded in a loop must not
    become a load on the API server).
    """

    JOBS_TTL_S = 5.0

    def __init__(self, config: StoreConfig, list_jobs: Callable[[], list[dict[str, Any]]],
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._bucket = config.bucket
        self._s3 = s3_client(config, max_attempts=3, connect_timeout=5, read_timeout=30)
        self._list_jobs = list_jobs
        self._clock = clock
        self._jobs: tuple[float, list[dict[str, Any]]] | None = None
        self._lock = threading.Lock()

    def _listed_jobs(self) -> list[dict[str, Any]]:
        with self._lock:
            if self._jobs is None or self._clock() - self._jobs[0] > self.JOBS_TTL_S:
                self._jobs = (self._clock(), self._list_jobs())
            return self._jobs[1]

    def open_last(self, cell: str, camera: str | None = None) -> OpenVideo | str:
        """The video, or why there is none (a sentence for the operator)."""
        job = last_stored_job(self._listed_jobs(), cell)
        if job is None:
            return f"no ended job on cell {cell} has its output stored yet"
        try:
            prefix = job_prefix(job.namespace, job.uid)
        except ValueError:
            prefix = ""
        if not prefix or job.location != f"s3://{self._bucket}/{prefix}":
            return (f"robotjob {job.namespace}/{job.name}'s output is not where this FMS reads "
                    f"(s3://{self._bucket}/<namespace>/<uid>/): no video")
        body = self._s3.get_object(Bucket=self._bucket, Key=prefix + MANIFEST_NAME)["Body"]
        try:
            manifest = body.read(MAX_MANIFEST_BYTES + 1)
        finally:
            body.close()
        if len(manifest) > MAX_MANIFEST_BYTES:
            return f"robotjob {job.namespace}/{job.name}'s manifest is larger than {MAX_MANIFEST_BYTES} bytes"
        video = video_in_manifest(manifest, prefix, camera)
        if video is None:
            which = f"camera {camera}" if camera else "a camera"
            return f"robotjob {job.namespace}/{job.name} (the last on cell {cell}) used no {which}: no video"
        stored = self._s3.get_object(Bucket=self._bucket, Key=video.key)
        length = stored.get("ContentLength")
        return OpenVideo(job, video.camera, length if isinstance(length, int) else None, _chunks(stored["Body"]))


def _chunks(body: Any) -> Iterator[bytes]:
    """The object's bytes; the connection goes back whether the browser read it all or left."""
    try:
        while chunk := body.read(CHUNK):
            yield bytes(chunk)
    finally:
        body.close()

"""The cell's video of a job: each camera the job used, as an MP4 file in the cell's record.

Why: the person who rented the cell, and its owner after an incident, want to see what the
arm did, whatever the job saved itself (the Real Robot Challenge sends camera logs of every
run; RoboArena and AutoEval keep each episode's videos). The connector already holds every
frame its cameras capture for the job, so it keeps them: ``videos/<camera>.mp4`` in the
cell's record of the job (``record_dir``, which the job cannot see), uploaded with the
job's output under ``armnet-cell/`` (docs/outputs.md, "The cell's record"). Beside each video,
``<camera>.json`` says when its first frame reached the connector (wall clock), so a viewer can
put it on the job's clock.

Off the job's path: a camera's capture thread hands a reference to each stored frame
(cameras store a new array per frame and never draw on a stored one) to a bounded queue,
at most ``MAX_FPS`` frames a second per camera; one thread encodes (H.264 in a fragmented
MP4, so a file cut short by a crash still plays up to its last fragment; each frame's time
is when it reached the connector, on the monotonic clock, so a camera that slowed down plays
at its real speed and a step of the wall clock changes nothing). A full queue
drops the frame and counts it, never waits; so does one past ``MAX_BYTES`` of video. A camera whose frame size changes (a job that
reconnects it at another resolution) starts a new file, ``<camera>-2.mp4``.
"""

from __future__ import annotations

import logging
import os
import queue
import re
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from armnet_core.cell_record import VIDEO_INFO_SUFFIX, VIDEOS, video_info

from .record_writer import RecordWriter

log = logging.getLogger(__name__)

#: Frames kept per camera and second: enough to see the motion, a bounded share of a core to encode.
MAX_FPS = 15.0
#: Frames waiting for the encoder, all cameras together; past it the newest is dropped.
QUEUE_SIZE = 8
#: How long ``stop`` encodes what is queued and closes the files.
DRAIN_S = 3.0
FOLDER = VIDEOS
CODEC = "libx264"
#: Fast and small: a record to look at, not a dataset (the job's own recording keeps its frames).
CODEC_OPTIONS = {"preset": "ultrafast", "crf": "28", "tune": "zerolatency"}
#: Fragments as the file grows: a file cut short by a crash plays up to its last fragment.
CONTAINER_OPTIONS = {"movflags": "frag_keyframe+empty_moov+default_base_moof", "flush_packets": "1"}
#: A keyframe (and so a fragment) at least this often, in frames.
KEYFRAME_INTERVAL = 30
#: Bytes of video one job may leave, all cameras together (hours at 640x480); past it frames are dropped.
MAX_BYTES = 4 * 1024**3
#: Frames between looks at the files' sizes.
SIZE_CHECK_FRAMES = 30
#: Files one camera may leave (a new one per frame size): a job reconnecting at ever new sizes stays bounded.
MAX_FILES_PER_CAMERA = 8

_SAFE_NAME = re.compile(r"[^A-Za-z0-9._-]")


class VideoCounters(Protocol):
    video_frames_written: int
    video_frames_dropped: int


@dataclass
class _Stream:
    """One open file of one camera."""

    path: Path
    container: Any
    stream: Any
    shape: tuple[int, ...]
    #: The first frame's ``time.monotonic()``: presentation times count from it.
    first_at: float
    last_pts: int = -1


@dataclass
class _Camera:
    name: str
    #: When the next frame is due (``time.monotonic()``); a frame up to a quarter period early counts as on time.
    due: float = 0.0
    files: int = 0
    open: _Stream | None = None
    problems: set[str] = field(default_factory=set)


class CameraVideo(RecordWriter):
    """``tap(camera)`` gives a camera's capture thread its frame sink; ``start``/``stop`` with the connector
    (``record_writer``: the stop encodes what is queued within its drain time and closes every file)."""

    thread_name = "armnet-camera-video"
    default_drain_s = DRAIN_S

    def __init__(self, directory: Path, counters: VideoCounters, *, max_fps: float = MAX_FPS) -> None:
        super().__init__()
        self.directory = directory / FOLDER
        self._counters = counters
        self._period = 1.0 / max_fps if max_fps > 0 else 0.0
        self._queue: queue.Queue[tuple[_Camera, Any, float]] = queue.Queue(maxsize=QUEUE_SIZE)
        self._cameras: dict[str, _Camera] = {}
        self._guard = threading.Lock()
        #: Bytes of the files closed so far, and frames since the last look at the open ones.
        self._closed_bytes = 0
        self._since_check = 0
        self._full = False

    def tap(self, camera: str) -> Callable[[Any, float], None]:
        """The sink for ``camera``'s frames (the cell's camera name): call it with each frame the camera
        captured and the ``time.monotonic()`` it arrived."""
        with self._guard:
            state = self._cameras.get(camera)
            if state is None:
                state = self._cameras[camera] = _Camera(camera)

        period = self._period

        def take(frame: Any, at: float) -> None:
            if at < state.due - period / 4:
                return
            # On the grid while the camera keeps up; a camera that paused starts a new one.
            state.due = state.due + period if at - state.due < period else at + period
            try:
                self._queue.put_nowait((state, frame, at))
            except queue.Full:
                self._counters.video_frames_dropped += 1
        return take

    def _cameras_now(self) -> list[_Camera]:
        with self._guard:  # a job may open another camera while the encoder looks
            return list(self._cameras.values())

    # -- the encoder's thread -----------------------------------------------------------------

    def _run(self) -> None:
        import av  # noqa: F401 — at the start, off the job's path, not at the first frame

        try:
            while not (self.draining() or (self.closing.is_set() and self._queue.empty())):
                try:
                    camera, frame, at = self._queue.get(timeout=0.1)
                except queue.Empty:
                    continue
                self._encode(camera, frame, at)
            left = self._queue.qsize()
            if left:
                self._counters.video_frames_dropped += left
        finally:
            for camera in self._cameras_now():
                self._close(camera)

    def _encode(self, camera: _Camera, frame: Any, at: float) -> None:
        try:
            if self._full or self._over_budget():
                self._counters.video_frames_dropped += 1
                return
            image = _picture(frame)
            if image is None:
                self._problem(camera, "its frames are not 8-bit RGB or grey pictures")
                self._counters.video_frames_dropped += 1
                return
            stream = camera.open
            if stream is None or stream.shape != image.shape:
                self._close(camera)
                if camera.files >= MAX_FILES_PER_CAMERA:
                    self._problem(camera, f"its frame size changed past {MAX_FILES_PER_CAMERA} files")
                    self._counters.video_frames_dropped += 1
                    return
                stream = camera.open = self._open(camera, image.shape, at)
            pts = round((at - stream.first_at) * 1000)
            if pts <= stream.last_pts:
                pts = stream.last_pts + 1  # a clock that stood still: keep the order
            stream.last_pts = pts
            self._write(stream, image, pts)
            self._counters.video_frames_written += 1
        except Exception as exc:  # noqa: BLE001 — a frame lost is counted; the job goes on
            self._counters.video_frames_dropped += 1
            self._problem(camera, f"{type(exc).__name__}: {str(exc)[:200]}")

    def _over_budget(self) -> bool:
        """Whether the job's videos reached ``MAX_BYTES`` (looked at every ``SIZE_CHECK_FRAMES`` frames)."""
        self._since_check += 1
        if self._since_check < SIZE_CHECK_FRAMES:
            return False
        self._since_check = 0
        open_bytes = sum(c.open.path.stat().st_size for c in self._cameras_now() if c.open is not None)
        if self._closed_bytes + open_bytes < MAX_BYTES:
            return False
        self._full = True
        log.warning("camera video: %d bytes written, the most one job keeps; the files are closed and later "
                    "frames counted, not kept", self._closed_bytes + open_bytes)
        for camera in self._cameras_now():
            self._close(camera)
        return True

    def _open(self, camera: _Camera, shape: tuple[int, ...], at: float) -> _Stream:
        import av

        self.directory.mkdir(parents=True, exist_ok=True)
        camera.files += 1
        stem = _SAFE_NAME.sub("_", camera.name) or "camera"
        path = self.directory / (f"{stem}.mp4" if camera.files == 1 else f"{stem}-{camera.files}.mp4")
        # The info says when the first frame arrived on the wall clock (the frames' own times are monotonic).
        arrived = time.time() - (time.monotonic() - at)
        _write_atomically(path.with_suffix(VIDEO_INFO_SUFFIX), video_info(camera.name, arrived, shape[1], shape[0]))
        container = av.open(str(path), mode="w", format="mp4", options=dict(CONTAINER_OPTIONS))
        try:
            stream: Any = container.add_stream(CODEC, rate=round(1.0 / self._period) if self._period else 30,
                                          options=dict(CODEC_OPTIONS))
            stream.width, stream.height = shape[1], shape[0]
            stream.pix_fmt = "yuv420p"
            stream.time_base = _millisecond()
            stream.codec_context.time_base = _millisecond()
            stream.codec_context.gop_size = KEYFRAME_INTERVAL
            stream.codec_context.thread_count = 1  # a bounded share of the connector's CPU
        except Exception:
            container.close()
            raise
        log.info("camera video: recording %s to %s", camera.name, path.name)
        return _Stream(path, container, stream, shape, at)

    @staticmethod
    def _write(stream: _Stream, image: Any, pts: int) -> None:
        import av

        picture = av.VideoFrame.from_ndarray(image, format="rgb24" if image.ndim == 3 else "gray")
        picture.pts = pts
        picture.time_base = _millisecond()
        for packet in stream.stream.encode(picture):
            stream.container.mux(packet)

    def _close(self, camera: _Camera) -> None:
        stream, camera.open = camera.open, None
        if stream is None:
            return
        try:
            for packet in stream.stream.encode(None):
                stream.container.mux(packet)
        except Exception as exc:  # noqa: BLE001 — the file still plays to its last fragment
            self._problem(camera, f"closing {stream.path.name}: {type(exc).__name__}: {str(exc)[:200]}")
        finally:
            stream.container.close()
            try:
                self._closed_bytes += stream.path.stat().st_size
            except OSError:
                pass

    @staticmethod
    def _problem(camera: _Camera, why: str) -> None:
        if why not in camera.problems and len(camera.problems) < 8:
            camera.problems.add(why)
            log.warning("camera video of %s: frames not kept: %s", camera.name, why)


def _write_atomically(path: Path, data: bytes) -> None:
    partial = path.with_name(f".{path.name}.partial")
    partial.write_bytes(data)
    os.replace(partial, path)


def _picture(frame: Any) -> Any | None:
    """``frame`` as an even-sized 8-bit RGB or grey picture (what H.264's 4:2:0 takes), or None."""
    import numpy as np

    if type(frame) is not np.ndarray or frame.dtype != np.uint8:
        return None
    if frame.ndim == 3 and frame.shape[2] == 1:
        frame = frame[:, :, 0]
    if not (frame.ndim == 2 or (frame.ndim == 3 and frame.shape[2] == 3)):
        return None
    height, width = frame.shape[0] & ~1, frame.shape[1] & ~1
    if height < 2 or width < 2:
        return None
    if (height, width) != frame.shape[:2]:
        frame = frame[:height, :width]
    return np.ascontiguousarray(frame)


def _millisecond() -> Any:
    from fractions import Fraction

    return Fraction(1, 1000)

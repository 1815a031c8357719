"""The cell's own pictures of each rollout: its first and last frame, and the frame the monitor judged.

Why: a verdict of the completion monitor is audited, and overruled, by a person looking at
the scene; a classifier is retrained on the frames it got wrong (AutoEval keeps them). So
for every rollout of a job on a cell with a monitor, the connector keeps the monitored
camera's newest scored frame at the rollout's begin (``first.jpg``), when the monitor's
verdict is recorded (``verdict.jpg``) and at its end (``last.jpg``), in the cell's record
of the job (``record_dir``: a directory the job cannot see or write). The node agent
uploads it with the job's output under ``armnet-cell/`` (docs/outputs.md).

Off the job's path: a rollout call only hands a reference to the monitor's newest frame
(cameras store a new array per frame and never draw on a stored one) to a bounded queue;
one thread encodes JPEG and writes each file atomically. A full queue or a rollout past
``MAX_ROLLOUTS`` drops the picture and counts it, never waits. Each rollout has its own
folder, ``rollouts/<index>-<begin time>/``, so a job that reuses an index keeps both.
"""

from __future__ import annotations

import logging
import os
import queue
import threading
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Protocol

from .record_writer import RecordWriter

log = logging.getLogger(__name__)

#: Rollouts of one job whose pictures are kept (three JPEGs each, tens of KiB at 640x480).
MAX_ROLLOUTS = 1000
#: Pictures waiting to be written; past it the newest is dropped (the writer is behind).
QUEUE_SIZE = 32
JPEG_QUALITY = 90
#: How long ``stop`` waits for the pictures still queued (the job has ended: the upload follows).
DRAIN_S = 5.0


class FrameCounters(Protocol):
    rollout_frames_kept: int
    rollout_frames_dropped: int


@dataclass(frozen=True)
class _Picture:
    folder: str
    name: str
    image: Any


class RolloutFrames(RecordWriter):
    """``begun``/``judged``/``ended`` from the connector's rollout calls; ``start``/``stop`` with the connector
    (``record_writer``: the stop writes what is queued within its drain time; the rest is counted dropped)."""

    thread_name = "armnet-rollout-frames"
    default_drain_s = DRAIN_S

    def __init__(self, directory: Path, latest: Callable[[], Any | None], counters: FrameCounters) -> None:
        """``latest()``: the monitor's newest scored frame (a BGR array), or None before its first."""
        super().__init__()
        self.directory = directory
        self._latest = latest
        self._counters = counters
        self._queue: queue.Queue[_Picture] = queue.Queue(maxsize=QUEUE_SIZE)
        self._lock = threading.Lock()
        self._folder: str | None = None  # the open rollout's folder
        #: The open rollout began before the monitor scored its first frame: its first picture is that frame.
        self._first_pending = False
        self._rollouts = 0

    # -- the connector's rollout calls (the job's threads) ---------------------------------

    def begun(self, index: int | None, at: float) -> None:
        """A rollout began: its folder, and its first picture."""
        with self._lock:
            self._folder = None
            self._first_pending = False
            if self._rollouts >= MAX_ROLLOUTS:
                self._counters.rollout_frames_dropped += 1
                return
            self._rollouts += 1
            stamp = datetime.fromtimestamp(at, UTC).strftime("%Y%m%dT%H%M%S.%f")[:-3] + "Z"
            self._folder = f"rollouts/{max(int(index or 0), 0):06d}-{stamp}"
        if not self._take("first"):
            with self._lock:  # a job's first rollout may begin before the monitor's camera gave a frame
                self._first_pending = self._folder is not None

    def scored(self, image: Any) -> None:
        """The monitor scored a frame (its thread): the first picture of a rollout that began without one."""
        with self._lock:
            folder, pending = self._folder, self._first_pending
            self._first_pending = False
        if pending and folder is not None:
            self._queue_picture(_Picture(folder, "first", image))

    def judged(self) -> None:
        """The monitor's verdict on the open rollout was recorded: the frame it rests on."""
        self._take("verdict")

    def ended(self) -> None:
        """The open rollout ended: its last picture; later pictures belong to no rollout."""
        self._take("last")
        with self._lock:
            self._folder = None
            self._first_pending = False

    def _take(self, name: str) -> bool:
        """Queue the monitor's newest scored frame as ``name`` of the open rollout; False: no frame yet."""
        with self._lock:
            folder = self._folder
        if folder is None:
            return True
        image = self._latest()
        if image is None:
            return False  # the monitor has scored nothing yet: no picture of the scene to keep
        self._queue_picture(_Picture(folder, name, image))
        return True

    def _queue_picture(self, picture: _Picture) -> None:
        try:
            self._queue.put_nowait(picture)
        except queue.Full:
            self._counters.rollout_frames_dropped += 1

    # -- the writer's thread --------------------------------------------------------------

    def _run(self) -> None:
        while not (self.draining() or (self.closing.is_set() and self._queue.empty())):
            try:
                picture = self._queue.get(timeout=0.1)
            except queue.Empty:
                continue
            if self.draining():
                self._counters.rollout_frames_dropped += 1
                break
            try:
                self._write(picture)
                self._counters.rollout_frames_kept += 1
            except Exception as exc:  # noqa: BLE001 — a picture lost is counted; the job goes on
                self._counters.rollout_frames_dropped += 1
                log.warning("rollout frames: %s/%s.jpg not kept: %s: %s", picture.folder, picture.name,
                            type(exc).__name__, str(exc)[:200])
        left = self._queue.qsize()
        if left:
            self._counters.rollout_frames_dropped += left
            log.warning("rollout frames: %d pictures not kept (the writer was behind at the stop)", left)

    def _write(self, picture: _Picture) -> None:
        import cv2

        ok, encoded = cv2.imencode(".jpg", picture.image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        if not ok:
            raise ValueError("the frame could not be encoded as JPEG")
        folder = self.directory / picture.folder
        folder.mkdir(parents=True, exist_ok=True)
        target = folder / f"{picture.name}.jpg"
        partial = folder / f".{picture.name}.jpg.partial"
        with open(partial, "wb") as file:
            file.write(encoded.tobytes())
        os.replace(partial, target)  # the upload never takes a half-written picture

"""The connector's side of camera frames through shared memory: creating and writing frame areas.

This module owns the frame areas of one connector (one job): a file per camera
object in the socket directory, created fresh with mode 0440 (no one may open it
for writing, the connector keeps the one writable mapping it made at creation),
group-owned by the socket directory's group (the pod's ``fsGroup``), and removed
when the camera object goes away. Each area holds a few slots used in turn; a
frame is written under its slot's sequence word (a seqlock), so a reader copying
an older frame sees that it was overwritten instead of a torn picture.

It never reads anything back from an area (the customer can map it, so nothing
in it is trusted) and never waits for a reader: a slow or dead reader costs the
connector nothing. The byte layout is ``armnet_runtime.frames``'s.
"""

from __future__ import annotations

import contextlib
import logging
import mmap
import os
import secrets
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from armnet_runtime.frames import (
    AREA_HEADER,
    FRAME_DTYPE_KINDS,
    HEADER_BYTES,
    MAGIC,
    MAX_DIMS,
    MAX_FRAME_BYTES,
    PAGE,
    SLOT_HEADER,
    STATE,
    STATE_AT,
    VERSION,
    slot_data_offset,
    slot_header_offset,
)

log = logging.getLogger(__name__)

SLOTS = 4
"""Slots per area: a reader has three newer frames' time to finish its copy."""

FRAME_LOCK_WAIT_S = 0.05
"""How long the capture thread waits for its camera's frame lock before skipping one publication."""

AREA_MODE = 0o440
MEMORY_FILESYSTEMS = frozenset({"tmpfs", "ramfs", "hugetlbfs"})

_seq = struct.Struct("<Q")


def filesystem_type(path: Path) -> str:
    """The type of the filesystem ``path`` lives on, from /proc/self/mountinfo ("" if unknown)."""
    target = os.path.realpath(path)
    best, kind = "", ""
    try:
        lines = Path("/proc/self/mountinfo").read_text().splitlines()
    except OSError:
        return ""
    for line in lines:
        fields = line.split(" - ", 1)
        left = fields[0].split()
        if len(fields) != 2 or len(left) < 5:
            continue
        mount = left[4].replace("\\040", " ")
        inside = target == mount or target.startswith(mount.rstrip("/") + "/")
        if inside and len(mount) >= len(best):
            best, kind = mount, fields[1].split()[0]
    return kind


class FrameArea:
    """One camera object's area: created on its first frame, replaced when a frame outgrows it."""

    def __init__(self, directory: Path, camera: str, slot_bytes: int) -> None:
        self.name = f"frames-{secrets.token_hex(8)}.shm"
        self.path = directory / self.name
        self.camera = camera
        self.slot_bytes = slot_bytes
        size = HEADER_BYTES + SLOTS * slot_bytes
        flags = os.O_RDWR | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC
        fd = os.open(self.path, flags, AREA_MODE)
        try:
            os.fchmod(fd, AREA_MODE)  # whatever the umask left
            group = os.stat(directory).st_gid
            if os.fstat(fd).st_gid != group:
                with contextlib.suppress(PermissionError):
                    os.fchown(fd, -1, group)
            os.ftruncate(fd, size)
            self._map = mmap.mmap(fd, size, prot=mmap.PROT_READ | mmap.PROT_WRITE)
        except BaseException:
            os.close(fd)
            with contextlib.suppress(OSError):
                self.path.unlink()
            raise
        os.close(fd)
        self.newest = 0
        AREA_HEADER.pack_into(self._map, 0, MAGIC, VERSION, SLOTS, slot_bytes, HEADER_BYTES)
        self._sequence = 0
        self._state_word = 0
        self._connected = False

    def set_state(self, connected: bool, newest: int | None = None) -> None:
        """Update the state block under its seqlock: connected, and the newest frame (0: none)."""
        self._connected = connected
        self._state_word += 2
        _seq.pack_into(self._map, STATE_AT, self._state_word - 1)
        STATE.pack_into(self._map, STATE_AT, self._state_word - 1, int(connected), newest or 0)
        _seq.pack_into(self._map, STATE_AT, self._state_word)

    def write(self, frame: Any, timestamp: float) -> dict[str, Any]:
        """Write ``frame`` (a C-contiguous native ndarray that fits) into the next slot; its descriptor."""
        import numpy as np

        self._sequence += 1
        sequence = self._sequence
        slot = sequence % SLOTS
        header = slot_header_offset(slot)
        nbytes = frame.nbytes
        _seq.pack_into(self._map, header, 2 * sequence - 1)  # odd: being written
        start = slot_data_offset(HEADER_BYTES, self.slot_bytes, slot)
        np.frombuffer(self._map, np.uint8, nbytes, start)[:] = frame.reshape(-1).view(np.uint8)
        dims = list(frame.shape) + [0] * (MAX_DIMS - frame.ndim)
        name = frame.dtype.name
        SLOT_HEADER.pack_into(self._map, header, 2 * sequence, nbytes, timestamp, frame.ndim, name.encode(), *dims)
        self.newest = sequence
        self.set_state(self._connected, sequence)
        return {
            "area": self.name, "camera": self.camera, "slot": slot, "sequence": sequence,
            "shape": list(frame.shape), "dtype": name, "timestamp": timestamp,
        }

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.path.unlink()
        with contextlib.suppress(BufferError):
            self._map.close()


@dataclass
class FrameCounters:
    """What an operator watches of the frame path (exported with the connector's counters)."""

    #: Frames written into an area (by capture threads and by reads).
    published: int = 0
    #: Areas created (one per camera object, plus one per frame-size growth).
    areas: int = 0
    #: Cameras whose frames go inline because no area could be created.
    inline_cameras: int = 0


class FramePublisher:
    """Publishes one camera object's frames; ``publish`` returns a descriptor or None (send inline)."""

    def __init__(self, directory: Path, camera: str, counters: FrameCounters | None = None) -> None:
        self.directory = directory
        self.camera = camera
        self.counters = counters if counters is not None else FrameCounters()
        self._area: FrameArea | None = None
        self._lock = threading.Lock()
        self._broken = False
        self._connected = False
        #: Also hands each captured frame to the cell's video of the job (``camera_video``), with its ``monotonic`` time.
        self.tap: Callable[[Any, float], None] | None = None

    def publish(self, frame: Any, timestamp: float | None = None, *, captured: bool = False) -> dict[str, Any] | None:
        """``captured``: a frame the camera's capture thread just stored (each goes to ``tap`` once; a read's
        reply publishes a stored frame again)."""
        import numpy as np

        if type(frame) is not np.ndarray:
            return None
        if captured and self.tap is not None:
            self.tap(frame, time.monotonic())
        if self._broken:
            return None
        if frame.dtype.kind not in FRAME_DTYPE_KINDS or frame.ndim > MAX_DIMS or frame.nbytes > MAX_FRAME_BYTES:
            return None
        if not frame.flags.c_contiguous or not frame.dtype.isnative:
            frame = np.ascontiguousarray(frame, dtype=frame.dtype.newbyteorder("="))
        stamp = time.monotonic() if timestamp is None else float(timestamp)
        with self._lock:  # two threads of one connection must not share a slot
            area = self._area
            if area is None or frame.nbytes > area.slot_bytes:
                area = self._replace_area(frame.nbytes)
                if area is None:
                    return None
                area.set_state(self._connected)
            self.counters.published += 1
            return area.write(frame, stamp)

    def set_connected(self, connected: bool) -> None:
        """The camera object was connected or disconnected; a disconnect forgets the newest frame.

        While the area says "connected" with a fresh frame, the SDK serves
        ``read_latest`` from it without a request; otherwise it asks.
        """
        with self._lock:
            self._connected = connected
            if self._area is not None:
                if not connected:
                    self._area.newest = 0
                self._area.set_state(connected, self._area.newest)

    def attach(self, camera: Any) -> bool:
        """Publish every frame ``camera``'s capture thread stores, as it stores it.

        LeRobot cameras (``OpenCVCamera`` and the simulator's) store each frame in
        ``latest_frame``/``latest_timestamp`` under ``frame_lock`` and then set
        ``new_frame_event``; the event is swapped for one that publishes first.
        False (nothing attached) for a camera without those attributes.
        """
        event = getattr(camera, "new_frame_event", None)
        if not isinstance(event, threading.Event) or not hasattr(camera, "frame_lock"):
            return False
        camera.new_frame_event = _PublishingEvent(self, camera, event.is_set())
        return True

    def _publish_stored(self, camera: Any) -> None:
        # Bounded: a camera that signalled while still holding its lock must not deadlock
        # its own capture thread here; that frame is then published on request only.
        lock = camera.frame_lock
        if not lock.acquire(timeout=FRAME_LOCK_WAIT_S):
            return
        try:
            frame, stamp = camera.latest_frame, camera.latest_timestamp
        finally:
            lock.release()
        if frame is not None:
            self.publish(frame, stamp if isinstance(stamp, float) else None, captured=True)

    def _replace_area(self, nbytes: int) -> FrameArea | None:
        if self._area is not None:
            self._area.close()
            self._area = None
        slot_bytes = max(PAGE, -(-nbytes // PAGE) * PAGE)
        try:
            self._area = FrameArea(self.directory, self.camera, slot_bytes)
        except OSError as exc:
            self._broken = True
            self.counters.inline_cameras += 1
            log.warning(
                "camera %s: cannot create a frame area in %s (%s); its frames travel inline in the replies",
                self.camera, self.directory, exc,
            )
            return None
        self.counters.areas += 1
        return self._area

    def close(self) -> None:
        """The camera object is gone: readers fall back to asking (and learn it is gone); no more frames."""
        self.tap = None
        with self._lock:
            self._broken = True
            if self._area is not None:
                self._area.set_state(False)
                self._area.close()
                self._area = None


class _PublishingEvent(threading.Event):
    """A camera's ``new_frame_event`` that publishes the stored frame before waking the waiters."""

    def __init__(self, publisher: FramePublisher, camera: Any, already_set: bool) -> None:
        super().__init__()
        self._publisher = publisher
        self._camera = camera
        self._failed = False
        if already_set:
            super().set()

    def set(self) -> None:
        if not self._failed:
            try:
                self._publisher._publish_stored(self._camera)
            except Exception:  # noqa: BLE001 — the capture thread must keep running whatever happens here
                self._failed = True
                log.exception("camera %s: publishing frames failed; they are sent on request only", self._camera)
        super().set()


class FrameAreas:
    """The frame areas of one connector: where they live, and a publisher per camera object."""

    def __init__(self, directory: Path) -> None:
        self.directory = Path(directory)
        self.counters = FrameCounters()
        self._checked = False
        self._guard = threading.Lock()

    def publisher(self, camera: str) -> FramePublisher:
        with self._guard:
            if not self._checked:
                self._checked = True
                kind = filesystem_type(self.directory)
                if kind not in MEMORY_FILESYSTEMS:
                    log.warning(
                        "frame areas live in %s, on %s, not a memory filesystem: frames still work, but the "
                        "kernel may write them back to disk. Mount a tmpfs there (in a pod: an emptyDir with "
                        "medium: Memory).", self.directory, kind or "an unknown filesystem",
                    )
        return FramePublisher(self.directory, camera, self.counters)

"""Camera frames through shared memory: the area format and its reader (runtime/PROTOCOL.md).

The connector publishes a camera's frames into a *frame area*, a file in the
socket directory (a tmpfs: in a pod an ``emptyDir`` with ``medium: Memory``), and
answers a camera read with a small descriptor instead of the pixels. This module
owns the area's byte layout (shared with the connector's writer) and the SDK side:
mapping an area read-only, checking a descriptor against the area, and copying
one frame out into an ndarray the caller owns.

It never writes into an area and never trusts a descriptor: every field is
bounded by the area's own header, and the slot's sequence word is checked before
and after the copy (a seqlock), so a frame overwritten during the copy is
reported as :class:`FrameOverwritten`, never returned torn. Only the standard
library is imported here; numpy is imported when a frame is copied.
"""

from __future__ import annotations

import math
import mmap
import os
import re
import struct
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from armnet_runtime.errors import ProtocolError

MAGIC = b"ARMNETFA"
VERSION = 1
PAGE = 4096
HEADER_BYTES = PAGE
"""Slot data starts on the second page; the first holds the area and slot headers."""

AREA_HEADER = struct.Struct("<8sIIQQ")
"""At 0: magic, version, slot count, slot capacity in bytes, offset of slot 0's data."""

STATE_AT = 64
STATE = struct.Struct("<QQQ")
"""At 64: seqlock word (odd while it changes), connected (0/1), newest frame's sequence (0: none)."""

SLOT_HEADERS_AT = 128
SLOT_HEADER_STRIDE = 128
SLOT_HEADER = struct.Struct("<QQdI4x16s8Q")
"""Per slot: seqlock word (2n-1 while frame n is written, 2n once whole), bytes, timestamp,
number of dimensions, dtype name, shape (8 dimensions at most)."""

MAX_SLOTS = 15
MAX_FRAME_BYTES = 64 * 1024 * 1024
"""Largest frame published through an area (a 4K RGB frame is ~25 MiB)."""

MAX_DIMS = 8
KEPT_AREAS = 3
FRAME_DTYPE_KINDS = frozenset("biuf")
AREA_NAME = re.compile(r"frames-[A-Za-z0-9_-]{1,64}\.shm")
"""An area's file name: no path, so a descriptor can only name a file in the socket directory."""

_seq = struct.Struct("<Q")


class FrameOverwritten(Exception):
    """The slot was reused for a newer frame while it was being copied; ask again."""


def slot_header_offset(slot: int) -> int:
    return SLOT_HEADERS_AT + slot * SLOT_HEADER_STRIDE


def slot_data_offset(data_offset: int, slot_bytes: int, slot: int) -> int:
    return data_offset + slot * slot_bytes


@dataclass(frozen=True)
class FrameDescriptor:
    """What a camera read's reply says about the frame it published (never the pixels)."""

    area: str
    camera: str
    slot: int
    sequence: int
    shape: tuple[int, ...]
    dtype: str
    timestamp: float

    @classmethod
    def parse(cls, obj: Any) -> FrameDescriptor:
        """Check every field's type and bound; ``ProtocolError`` naming the bad field otherwise."""
        if type(obj) is not dict:
            raise ProtocolError(f"frame descriptor must be an object, got {type(obj).__name__}")
        try:
            area, camera, slot = obj["area"], obj["camera"], obj["slot"]
            sequence, shape, dtype, timestamp = obj["sequence"], obj["shape"], obj["dtype"], obj["timestamp"]
        except KeyError as exc:
            raise ProtocolError(f"frame descriptor lacks the field {exc.args[0]!r}") from None
        if type(area) is not str or not AREA_NAME.fullmatch(area):
            raise ProtocolError(f"frame descriptor names no frame area of this socket directory: {area!r:.80}")
        if type(camera) is not str or len(camera) > 256:
            raise ProtocolError("frame descriptor 'camera' must be a short string")
        if type(slot) is not int or not 0 <= slot < MAX_SLOTS:
            raise ProtocolError(f"frame descriptor 'slot' must be an int in [0, {MAX_SLOTS}), got {slot!r:.40}")
        if type(sequence) is not int or not 1 <= sequence < 2**62:
            raise ProtocolError(f"frame descriptor 'sequence' must be a positive int, got {sequence!r:.40}")
        if (
            type(shape) is not list or len(shape) > MAX_DIMS
            or not all(type(n) is int and 0 <= n <= MAX_FRAME_BYTES for n in shape)
        ):
            raise ProtocolError(f"frame descriptor 'shape' must be up to {MAX_DIMS} non-negative ints, got {shape!r:.80}")
        if type(dtype) is not str or len(dtype) > 16:
            raise ProtocolError(f"frame descriptor 'dtype' must be a numpy dtype name, got {dtype!r:.40}")
        if type(timestamp) not in (int, float) or not math.isfinite(timestamp):
            raise ProtocolError("frame descriptor 'timestamp' must be a finite number")
        return cls(area, camera, slot, sequence, tuple(shape), dtype, float(timestamp))


class FrameArea:
    """One area mapped read-only: the SDK can copy frames out of it and can write nothing into it."""

    def __init__(self, path: Path) -> None:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
        try:
            size = os.fstat(fd).st_size
            if size < HEADER_BYTES:
                raise ProtocolError(f"frame area {path.name} is {size} bytes, smaller than its header")
            self._map = mmap.mmap(fd, size, prot=mmap.PROT_READ)
        finally:
            os.close(fd)
        magic, version, slots, slot_bytes, data_offset = AREA_HEADER.unpack_from(self._map, 0)
        if magic != MAGIC or version != VERSION:
            self.close()
            raise ProtocolError(f"{path.name} is not a version-{VERSION} armnet frame area")
        if not (
            0 < slots <= MAX_SLOTS and slot_bytes % PAGE == 0 and 0 < slot_bytes <= MAX_FRAME_BYTES
            and data_offset == HEADER_BYTES and data_offset + slots * slot_bytes <= size
        ):
            self.close()
            raise ProtocolError(f"frame area {path.name} has an inconsistent header")
        self.name = path.name
        self.slots: int = slots
        self.slot_bytes: int = slot_bytes
        self.data_offset: int = data_offset

    def copy(self, frame: FrameDescriptor) -> Any:
        """The frame as a new ndarray (one copy); ``FrameOverwritten`` if the slot moved on meanwhile."""
        if frame.slot >= self.slots:
            raise ProtocolError(f"frame descriptor names slot {frame.slot}; area {self.name} has {self.slots}")
        return self._copy(frame.slot, frame.sequence, frame.shape, frame.dtype)

    def latest(self, max_age_ms: float) -> Any | None:
        """The newest frame if the camera is connected and it is at most ``max_age_ms`` old, else None.

        None means "ask the connector": it then answers with the real camera's own
        error (not connected, no frame yet, too old) or a frame that just arrived.
        """
        state = self._map
        word = _seq.unpack_from(state, STATE_AT)[0]
        if word & 1:
            return None
        _, connected, sequence = STATE.unpack_from(state, STATE_AT)
        if _seq.unpack_from(state, STATE_AT)[0] != word or not connected or not sequence:
            return None
        slot = sequence % self.slots
        header = slot_header_offset(slot)
        written, _, timestamp, ndim, dtype, *dims = SLOT_HEADER.unpack_from(state, header)
        if written != 2 * sequence or ndim > MAX_DIMS or (time.perf_counter() - timestamp) * 1e3 > max_age_ms:
            return None
        try:
            return self._copy(slot, sequence, tuple(dims[:ndim]), dtype.rstrip(b"\0").decode("ascii"))
        except (FrameOverwritten, UnicodeDecodeError):
            return None

    def _copy(self, slot: int, sequence: int, shape: tuple[int, ...], dtype_name: str) -> Any:
        import numpy as np

        try:
            dtype = np.dtype(dtype_name)
        except TypeError:
            raise ProtocolError(f"frame dtype {dtype_name!r:.40} is not a numpy dtype") from None
        if dtype.kind not in FRAME_DTYPE_KINDS or not dtype.isnative:
            raise ProtocolError(f"frame dtype {dtype_name!r} is not allowed in a frame area")
        nbytes = math.prod(shape) * dtype.itemsize
        if nbytes > self.slot_bytes:
            raise ProtocolError(f"a frame of shape {shape} and {dtype} does not fit area {self.name}'s slots")
        header = slot_header_offset(slot)
        expected = 2 * sequence
        if _seq.unpack_from(self._map, header)[0] != expected:
            raise FrameOverwritten(f"frame {sequence} is no longer in slot {slot}")
        start = slot_data_offset(self.data_offset, self.slot_bytes, slot)
        out = np.empty(shape, dtype=dtype)
        out.reshape(-1).view(np.uint8)[:] = np.frombuffer(self._map, np.uint8, nbytes, start)
        if _seq.unpack_from(self._map, header)[0] != expected:
            raise FrameOverwritten(f"frame {sequence} was overwritten while it was copied")
        return out

    def close(self) -> None:
        try:
            self._map.close()
        except BufferError:  # an ndarray view is alive; the mapping goes with it
            pass


class FrameReader:
    """The frame areas one proxy has mapped, by name, in the socket directory of its endpoint.

    A camera has one live area; when a frame outgrows it the connector makes a new
    one (a new name). Superseded mappings stay open a little longer, so a thread
    still copying from one is never cut off; the oldest are closed beyond
    :data:`KEPT_AREAS`.
    """

    def __init__(self, directory: Path) -> None:
        self.directory = directory
        self._areas: dict[str, FrameArea] = {}
        self._current: FrameArea | None = None

    def copy(self, raw: Any) -> Any:
        """Parse a reply's descriptor and copy its frame out; ``ProtocolError``/``OSError`` when impossible."""
        frame = FrameDescriptor.parse(raw)
        area = self._areas.get(frame.area)
        if area is None:
            area = FrameArea(self.directory / frame.area)
            self._areas[frame.area] = area
            while len(self._areas) > KEPT_AREAS:
                self._areas.pop(next(iter(self._areas))).close()
        self._current = area
        return area.copy(frame)

    def latest(self, max_age_ms: float) -> Any | None:
        """The newest frame of the area last used, without asking the connector; None: ask it."""
        area = self._current
        return area.latest(max_age_ms) if area is not None else None

    def close(self) -> None:
        for area in self._areas.values():
            area.close()
        self._areas.clear()
        self._current = None

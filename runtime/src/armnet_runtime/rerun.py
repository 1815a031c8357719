"""Stream observation/action frames to the client's Rerun viewer through stdout.

:class:`RerunStreamer` owns a bounded queue and one background thread: the
control loop only appends (dropping the oldest frame when full), the thread
encodes a ``RerunPacket`` (schema: ``rerun_packet.proto`` next to this file)
and prints it as one ``[armnet:rerun]:b64`` marker line. The protobuf wire
format is written by hand here (varints, fixed64, length-delimited), so
protobuf is not a dependency; :func:`decode_packet` is the pure-Python reader
the agent and tests use. numpy and opencv are imported lazily, on first frame.
"""

from __future__ import annotations

import collections
import logging
import os
import struct
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Optional

from armnet_runtime import env as env_keys
from armnet_runtime.markers import format_rerun
from armnet_runtime.streams import emit_line

logger = logging.getLogger(__name__)

DEFAULT_QUEUE_MAXSIZE = 8
ENCODING_UNSPECIFIED = 0
ENCODING_JPEG = 1
ENCODING_RAW_U8 = 2

_WIRE_VARINT = 0
_WIRE_FIXED64 = 1
_WIRE_LEN = 2


# --- protobuf wire format -------------------------------------------------------------


def _varint(value: int) -> bytes:
    if value < 0:
        value += 1 << 64
    out = bytearray()
    while True:
        byte = value & 0x7F
        value >>= 7
        if value:
            out.append(byte | 0x80)
        else:
            out.append(byte)
            return bytes(out)


def _key(number: int, wire_type: int) -> bytes:
    return _varint((number << 3) | wire_type)


def _field_varint(number: int, value: int) -> bytes:
    return _key(number, _WIRE_VARINT) + _varint(value) if value else b""


def _field_bytes(number: int, value: bytes) -> bytes:
    return _key(number, _WIRE_LEN) + _varint(len(value)) + value if value else b""


def _field_double(number: int, value: float) -> bytes:
    return _key(number, _WIRE_FIXED64) + struct.pack("<d", value)


@dataclass(frozen=True)
class ImageData:
    width: int
    height: int
    channels: int
    encoding: int
    data: bytes


@dataclass(frozen=True)
class Entry:
    """One entity of a packet: a scalar or an image at ``path``."""

    path: str
    scalar: Optional[float] = None
    image: Optional[ImageData] = None


@dataclass(frozen=True)
class Packet:
    job_id: str
    timestamp_ns: int
    sequence: int
    dropped: int
    entries: tuple[Entry, ...] = field(default_factory=tuple)


def _encode_image(image: ImageData) -> bytes:
    return (
        _field_varint(1, image.width)
        + _field_varint(2, image.height)
        + _field_varint(3, image.channels)
        + _field_varint(4, image.encoding)
        + _field_bytes(5, image.data)
    )


def _encode_entry(entry: Entry) -> bytes:
    body = _field_bytes(1, entry.path.encode())
    if entry.scalar is not None:
        body += _field_double(2, entry.scalar)
    elif entry.image is not None:
        image = _encode_image(entry.image)
        body += _key(3, _WIRE_LEN) + _varint(len(image)) + image
    return body


def encode_packet(packet: Packet) -> bytes:
    """The protobuf encoding of ``packet`` (``armnet.rerun.v1.RerunPacket``)."""
    body = (
        _field_bytes(1, packet.job_id.encode())
        + _field_varint(2, packet.timestamp_ns)
        + _field_varint(3, packet.sequence)
        + _field_varint(4, packet.dropped)
    )
    for entry in packet.entries:
        encoded = _encode_entry(entry)
        body += _key(5, _WIRE_LEN) + _varint(len(encoded)) + encoded
    return body


def _read_varint(data: bytes, pos: int) -> tuple[int, int]:
    result = 0
    shift = 0
    while True:
        if pos >= len(data) or shift > 63:
            raise ValueError("truncated or oversized varint in Rerun packet")
        byte = data[pos]
        pos += 1
        result |= (byte & 0x7F) << shift
        if not byte & 0x80:
            return result, pos
        shift += 7


def _fields(data: bytes) -> list[tuple[int, int, Any]]:
    """Split a message into (field number, wire type, raw value); unknown wire types fail."""
    out: list[tuple[int, int, Any]] = []
    pos = 0
    while pos < len(data):
        key, pos = _read_varint(data, pos)
        number, wire_type = key >> 3, key & 7
        if wire_type == _WIRE_VARINT:
            value, pos = _read_varint(data, pos)
            out.append((number, wire_type, value))
        elif wire_type == _WIRE_FIXED64:
            if pos + 8 > len(data):
                raise ValueError("truncated fixed64 in Rerun packet")
            out.append((number, wire_type, data[pos:pos + 8]))
            pos += 8
        elif wire_type == _WIRE_LEN:
            length, pos = _read_varint(data, pos)
            if pos + length > len(data):
                raise ValueError("truncated length-delimited field in Rerun packet")
            out.append((number, wire_type, data[pos:pos + length]))
            pos += length
        elif wire_type == 5:
            out.append((number, wire_type, data[pos:pos + 4]))
            pos += 4
        else:
            raise ValueError(f"unsupported wire type {wire_type} in Rerun packet")
    return out


def _decode_image(data: bytes) -> ImageData:
    values: dict[int, Any] = {1: 0, 2: 0, 3: 0, 4: 0, 5: b""}
    for number, _, value in _fields(data):
        values[number] = value
    return ImageData(values[1], values[2], values[3], values[4], bytes(values[5]))


def _decode_entry(data: bytes) -> Entry:
    path = ""
    scalar: Optional[float] = None
    image: Optional[ImageData] = None
    for number, _, value in _fields(data):
        if number == 1:
            path = bytes(value).decode()
        elif number == 2:
            scalar = struct.unpack("<d", value)[0]
        elif number == 3:
            image = _decode_image(value)
    return Entry(path, scalar, image)


def decode_packet(data: bytes) -> Packet:
    """Decode a ``RerunPacket``; raises ``ValueError`` on a malformed packet."""
    job_id = ""
    numbers = {2: 0, 3: 0, 4: 0}
    entries: list[Entry] = []
    for number, _, value in _fields(data):
        if number == 1:
            job_id = bytes(value).decode()
        elif number in numbers:
            numbers[number] = value - (1 << 64) if number == 2 and value >= 1 << 63 else value
        elif number == 5:
            entries.append(_decode_entry(value))
    return Packet(job_id, numbers[2], numbers[3], numbers[4], tuple(entries))


# --- frame -> entries ---------------------------------------------------------------------


def _namespaced(prefix: str, key: str) -> str:
    return key if key.startswith(prefix + ".") else f"{prefix}.{key}"


def _image_entry(path: str, array: Any, compress: bool, quality: int) -> Entry:
    import numpy as np

    pixels = array
    if pixels.ndim == 3 and pixels.shape[0] in (1, 3, 4) and pixels.shape[-1] not in (1, 3, 4):
        pixels = np.transpose(pixels, (1, 2, 0))  # CHW -> HWC, as LeRobot's helper does
    if pixels.ndim == 2:
        pixels = pixels[:, :, None]
    if pixels.dtype != np.uint8:
        scale = 255.0 if np.issubdtype(pixels.dtype, np.floating) and pixels.max(initial=0) <= 1.0 else 1.0
        pixels = np.clip(pixels * scale, 0, 255).astype(np.uint8)
    pixels = np.ascontiguousarray(pixels)
    height, width, channels = (int(n) for n in pixels.shape)
    if compress and channels in (1, 3):
        jpeg = _jpeg(pixels, quality)
        if jpeg is not None:
            return Entry(path, image=ImageData(width, height, channels, ENCODING_JPEG, jpeg))
    return Entry(path, image=ImageData(width, height, channels, ENCODING_RAW_U8, pixels.tobytes()))


_warned_no_cv2 = False


def _jpeg(pixels: Any, quality: int) -> Optional[bytes]:
    global _warned_no_cv2
    try:
        import cv2
    except ImportError:
        if not _warned_no_cv2:
            _warned_no_cv2 = True
            logger.warning("opencv is not installed: sending raw images (pip install opencv-python-headless)")
        return None
    bgr = cv2.cvtColor(pixels, cv2.COLOR_RGB2BGR) if pixels.shape[2] == 3 else pixels
    ok, encoded = cv2.imencode(".jpg", bgr, [int(cv2.IMWRITE_JPEG_QUALITY), int(quality)])
    return bytes(encoded.tobytes()) if ok else None


def frame_entries(
    observation: Optional[dict[str, Any]],
    action: Optional[dict[str, Any]],
    *,
    compress_images: bool = True,
    jpeg_quality: int = 75,
) -> list[Entry]:
    """Turn one observation/action snapshot into packet entries (LeRobot's log_rerun_data rules).

    Scalars -> scalar; 1-D arrays and lists -> ``<key>_<i>`` scalars; 2-D/3-D
    arrays -> images. Values of other types (strings, None) are skipped.
    """
    entries: list[Entry] = []
    for prefix, data in (("observation", observation), ("action", action)):
        for key, value in (data or {}).items():
            path = _namespaced(prefix, str(key))
            entries.extend(_value_entries(path, value, compress_images, jpeg_quality))
    return entries


def _value_entries(path: str, value: Any, compress: bool, quality: int) -> list[Entry]:
    if isinstance(value, bool):
        return [Entry(path, scalar=float(value))]
    if isinstance(value, (int, float)):
        return [Entry(path, scalar=float(value))]
    if isinstance(value, (list, tuple)):
        return [
            Entry(f"{path}_{i}", scalar=float(v))
            for i, v in enumerate(value)
            if isinstance(v, (int, float))
        ]
    if hasattr(value, "ndim") and hasattr(value, "dtype"):
        import numpy as np

        array = np.asarray(value)
        if array.ndim == 0:
            return [Entry(path, scalar=float(array))]
        if array.ndim == 1:
            return [Entry(f"{path}_{i}", scalar=float(v)) for i, v in enumerate(array)]
        if array.ndim in (2, 3):
            return [_image_entry(path, array, compress, quality)]
    if hasattr(value, "item") and callable(value.item):  # torch / numpy scalar
        try:
            return [Entry(path, scalar=float(value.item()))]
        except (TypeError, ValueError):
            return []
    return []


# --- the streamer -------------------------------------------------------------------------


def _queue_maxsize() -> int:
    raw = os.environ.get(env_keys.RERUN_QUEUE_MAXSIZE)
    if not raw:
        return DEFAULT_QUEUE_MAXSIZE
    try:
        size = int(raw)
    except ValueError:
        size = 0
    if size < 1:
        logger.warning(
            "%s=%r is not a positive integer; using %d",
            env_keys.RERUN_QUEUE_MAXSIZE, raw, DEFAULT_QUEUE_MAXSIZE,
        )
        return DEFAULT_QUEUE_MAXSIZE
    return size


@dataclass
class _Frame:
    observation: Optional[dict[str, Any]]
    action: Optional[dict[str, Any]]
    compress_images: bool
    jpeg_quality: int
    timestamp_ns: int
    sequence: int


class RerunStreamer:
    """Encodes and prints Rerun packets on a background thread; ``submit`` never blocks."""

    def __init__(self, job_id: str, *, maxsize: Optional[int] = None) -> None:
        self.job_id = job_id
        self.maxsize = maxsize if maxsize is not None else _queue_maxsize()
        self._queue: collections.deque[_Frame] = collections.deque()
        self._cond = threading.Condition()
        self._thread: Optional[threading.Thread] = None
        self._stopping = False
        self._busy = False
        self._sequence = 0
        self._dropped_pending = 0
        self.dropped_total = 0
        self.sent_total = 0

    def start(self) -> None:
        """Start the worker thread (idempotent)."""
        with self._cond:
            if self._thread is not None:
                return
            self._stopping = False
            self._thread = threading.Thread(
                target=self._run, name=f"armnet-rerun-{self.job_id}", daemon=True
            )
            self._thread.start()

    def submit(
        self,
        observation: Optional[dict[str, Any]] = None,
        action: Optional[dict[str, Any]] = None,
        *,
        compress_images: bool = True,
        jpeg_quality: int = 75,
    ) -> None:
        """Queue one snapshot; when the queue is full the oldest pending snapshot is dropped."""
        frame = _Frame(
            dict(observation) if observation else None,
            dict(action) if action else None,
            compress_images,
            int(jpeg_quality),
            time.time_ns(),
            0,
        )
        with self._cond:
            frame.sequence = self._sequence
            self._sequence += 1
            while len(self._queue) >= self.maxsize:
                self._queue.popleft()
                self._dropped_pending += 1
                self.dropped_total += 1
            self._queue.append(frame)
            self._cond.notify_all()

    def flush(self, timeout: Optional[float] = 10.0) -> bool:
        """Wait until every queued snapshot is written; False if ``timeout`` passed first."""
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._cond:
            while self._queue or self._busy:
                if self._thread is None:
                    return False
                remaining = None if deadline is None else deadline - time.monotonic()
                if remaining is not None and remaining <= 0:
                    return False
                self._cond.wait(remaining)
        return True

    def stop(self, timeout: Optional[float] = 10.0) -> None:
        """Flush what is queued, then stop the worker."""
        self.flush(timeout)
        with self._cond:
            self._stopping = True
            thread, self._thread = self._thread, None
            self._cond.notify_all()
        if thread is not None:
            thread.join(timeout)

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._queue and not self._stopping:
                    self._cond.wait()
                if not self._queue:
                    return
                frame = self._queue.popleft()
                dropped, self._dropped_pending = self._dropped_pending, 0
                self._busy = True
            try:
                self._emit(frame, dropped)
            except Exception:  # noqa: BLE001 - visualisation must never kill the job
                logger.warning("rerun frame could not be encoded; skipped", exc_info=True)
            finally:
                with self._cond:
                    self._busy = False
                    self._cond.notify_all()

    def _emit(self, frame: _Frame, dropped: int) -> None:
        entries = frame_entries(
            frame.observation,
            frame.action,
            compress_images=frame.compress_images,
            jpeg_quality=frame.jpeg_quality,
        )
        packet = Packet(self.job_id, frame.timestamp_ns, frame.sequence, dropped, tuple(entries))
        emit_line(format_rerun(encode_packet(packet)))
        self.sent_total += 1

"""Rerun packets of a job's log stream: decoding, and what each entry becomes in Rerun (pure).

The job's ``RerunStreamer`` prints each packet as ``[armnet:rerun]:b64 <base64>``
and the agent republishes it on ``logs.<ns>.<jobId>.rerun``; the packet is
decoded by the SDK's own reader (``armnet_runtime.rerun.decode_packet``), whether
the agent sends the marker line, the base64 text, or the raw bytes. Which Rerun
archetype an entry becomes is decided here, without ``rerun-sdk``, so the rules
(and the refusal of a raw image whose bytes do not match its declared shape:
the packet comes from the job, which is tenant code) are tested everywhere;
:mod:`armnet_client.rerun_sink` only carries the decisions out.
"""

from __future__ import annotations

import base64
import binascii
import re
from dataclasses import dataclass
from typing import Any, Literal, Optional

from armnet_runtime.markers import RERUN_MARKER
from armnet_runtime.rerun import ENCODING_JPEG, ENCODING_RAW_U8, Entry, Packet, decode_packet

from .logwire import LogLine

ColorModel = Literal["L", "RGB", "RGBA"]

#: Rerun's color model for a raw ``uint8`` image of this many channels.
COLOR_MODELS: dict[int, ColorModel] = {1: "L", 3: "RGB", 4: "RGBA"}


def packet_of(line: LogLine) -> Optional[Packet]:
    """The packet a ``rerun`` line carries, or ``None`` for anything that does not decode."""
    if line.kind != "rerun":
        return None
    text = line.text.strip()
    if text.startswith(RERUN_MARKER):
        text = text[len(RERUN_MARKER):].strip()
    candidates: list[bytes] = []
    try:
        candidates.append(base64.b64decode(text, validate=True))
    except (binascii.Error, ValueError):
        pass
    if isinstance(line.data, bytes):
        candidates.append(line.data)
    for raw in candidates:
        try:
            return decode_packet(raw)
        except (ValueError, IndexError):
            continue
    return None


def packet_document(packet: Packet) -> dict[str, Any]:
    """``armnet view --dump``: one JSON object per packet (image bytes as their length)."""
    entries: list[dict[str, Any]] = []
    for entry in packet.entries:
        if entry.image is not None:
            image = entry.image
            entries.append({"path": entry.path, "image": {
                "width": image.width, "height": image.height, "channels": image.channels,
                "encoding": image.encoding, "bytes": len(image.data)}})
        else:
            entries.append({"path": entry.path, "scalar": entry.scalar})
    return {"job_id": packet.job_id, "timestamp_ns": packet.timestamp_ns,
            "sequence": packet.sequence, "dropped": packet.dropped, "entries": entries}


@dataclass(frozen=True)
class Scalar:
    """``rr.Scalars(value)`` at ``path``."""

    path: str
    value: float


@dataclass(frozen=True)
class Jpeg:
    """``rr.EncodedImage`` (``image/jpeg``) at ``path``: Rerun decodes it."""

    path: str
    data: bytes


@dataclass(frozen=True)
class RawImage:
    """``rr.Image`` of ``uint8`` pixels, row-major ``height x width x channels``."""

    path: str
    data: bytes
    width: int
    height: int
    color_model: ColorModel


@dataclass(frozen=True)
class Skipped:
    """An entry that cannot be shown, and why (said once per reason by the sink)."""

    path: str
    reason: str


Logged = Scalar | Jpeg | RawImage | Skipped


def entity_logs(entry: Entry) -> Logged:
    """What one packet entry becomes in Rerun; a malformed entry is skipped, never trusted."""
    if entry.scalar is not None:
        return Scalar(entry.path, entry.scalar)
    image = entry.image
    if image is None:
        return Skipped(entry.path, "an entry with neither a scalar nor an image")
    if image.encoding == ENCODING_JPEG:
        return Jpeg(entry.path, image.data)
    if image.encoding != ENCODING_RAW_U8:
        return Skipped(entry.path, f"an image with unknown encoding {image.encoding}")
    if image.channels not in COLOR_MODELS:
        return Skipped(entry.path, f"a raw image with {image.channels} channels (1, 3 or 4 are shown)")
    if image.width <= 0 or image.height <= 0 or len(image.data) != image.width * image.height * image.channels:
        return Skipped(entry.path, f"a raw image whose {len(image.data)} bytes do not fill "
                                   f"{image.width}x{image.height}x{image.channels}")
    return RawImage(entry.path, image.data, image.width, image.height, COLOR_MODELS[image.channels])


#: The latest instant and frame number Rerun's timelines take (its times are signed 64-bit
#: nanoseconds, so seconds beyond 2**62 ns round past the limit and overflow).
_MAX_TIME_NS = 1 << 62
_MAX_FRAME = (1 << 63) - 1


def timelines(packet: Packet) -> tuple[float, int]:
    """The packet's ``time`` (seconds since the epoch) and ``frame`` (its sequence), inside Rerun's range.

    Both come from the job: a value Rerun cannot hold is clamped, not allowed to end the replay.
    """
    seconds = min(max(packet.timestamp_ns, 0), _MAX_TIME_NS) / 1e9
    return seconds, min(max(packet.sequence, 0), _MAX_FRAME)


def application_id(job: str) -> str:
    """The Rerun application id for a job: ``armnet-<job>`` in the letters Rerun accepts as is.

    Rerun rewrites (and warns about) ids with ``/`` or ``.``; a RobotJob name may hold dots.
    """
    return "armnet-" + re.sub(r"[^A-Za-z0-9_-]", "-", job)

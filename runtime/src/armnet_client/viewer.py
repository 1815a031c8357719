"""Rerun packets of a job's log stream: decoding (pure) and replay into a local Rerun viewer.

The job's ``RerunStreamer`` prints each packet as ``[armnet:rerun]:b64 <base64>``
and the agent republishes it on ``logs.<ns>.<jobId>.rerun``; the packet is
decoded by the SDK's own reader (``armnet_runtime.rerun.decode_packet``), whether
the agent sends the marker line, the base64 text, or the raw bytes. Replaying
needs ``rerun-sdk`` (optional; imported only by :func:`replay`).
"""

from __future__ import annotations

import base64
import binascii
from collections.abc import Iterable
from typing import Any, Optional

from armnet_runtime.markers import RERUN_MARKER
from armnet_runtime.rerun import ENCODING_JPEG, Packet, decode_packet

from .logwire import LogLine


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


def replay(packets: Iterable[Packet], *, app_id: str, save: Optional[str]) -> int:
    """Log every entry into Rerun (a spawned viewer, or ``save`` as an .rrd); returns the count.

    Untested here: ``rerun-sdk`` does not install in this repository's venv.
    """
    try:
        import rerun as rr
    except ImportError as exc:
        raise RuntimeError("viewing needs rerun-sdk: pip install rerun-sdk (or use --dump)") from exc
    rr.init(app_id, spawn=save is None)
    if save is not None:
        rr.save(save)
    count = 0
    for packet in packets:
        rr.set_time("time", timestamp=packet.timestamp_ns / 1e9)
        for entry in packet.entries:
            if entry.image is not None and entry.image.encoding == ENCODING_JPEG:
                rr.log(entry.path, rr.EncodedImage(contents=entry.image.data, media_type="image/jpeg"))
            elif entry.image is not None:
                import numpy as np

                pixels = np.frombuffer(entry.image.data, dtype=np.uint8).reshape(
                    entry.image.height, entry.image.width, entry.image.channels)
                rr.log(entry.path, rr.Image(pixels))
            elif entry.scalar is not None:
                rr.log(entry.path, rr.Scalars(entry.scalar))
        count += 1
    return count

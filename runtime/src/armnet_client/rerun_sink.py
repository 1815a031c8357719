"""Replaying a job's Rerun packets into ``rerun-sdk``: a spawned viewer, or an ``.rrd`` file.

``rerun-sdk`` is optional (``pip install 'armnet-runtime[view]'``) and imported
only here, when a replay starts. What each entry becomes is decided by
:func:`armnet_client.viewer.entity_logs`; this module only logs it, on two
timelines: ``time`` (the job's clock when the frame was taken) and ``frame``
(the streamer's sequence number, which shows the frames it dropped as gaps).
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any, Optional

from armnet_runtime.rerun import Packet

from .errors import RerunMissing
from .viewer import Jpeg, RawImage, Scalar, Skipped, entity_logs, timelines

logger = logging.getLogger(__name__)

@dataclass(frozen=True)
class Replayed:
    """What a replay logged: packets, entries skipped as malformed, frames the job's streamer dropped."""

    packets: int
    skipped: int
    dropped: int


def _rerun() -> Any:
    try:
        import rerun
    except ImportError as exc:
        raise RerunMissing() from exc
    return rerun


def replay(packets: Iterable[Packet], *, app_id: str, save: Optional[str]) -> Replayed:
    """Log every packet into Rerun: into ``save`` (an ``.rrd``) if given, else a spawned viewer.

    The recording is finalized before returning, so the file is complete (and
    readable by ``rerun.chunk.RrdReader`` or ``rerun out.rrd``) once this returns.
    """
    rr = _rerun()
    count = skipped = dropped = 0
    said: set[str] = set()
    with rr.RecordingStream(app_id) as rec:
        if save is not None:
            rec.save(save)
        else:
            rec.spawn()
        for packet in packets:
            seconds, frame = timelines(packet)
            rec.set_time("time", timestamp=seconds)
            rec.set_time("frame", sequence=frame)
            for entry in packet.entries:
                logged = entity_logs(entry)
                if isinstance(logged, Scalar):
                    rec.log(logged.path, rr.Scalars(logged.value))
                elif isinstance(logged, Jpeg):
                    rec.log(logged.path, rr.EncodedImage(contents=logged.data, media_type="image/jpeg"))
                elif isinstance(logged, RawImage):
                    rec.log(logged.path, rr.Image(bytes=logged.data, width=logged.width, height=logged.height,
                                                  color_model=logged.color_model, datatype="u8"))
                else:
                    skipped += 1
                    _say_once(logged, said)
            count += 1
            dropped += packet.dropped
    return Replayed(count, skipped, dropped)


def _say_once(skipped: Skipped, said: set[str]) -> None:
    if skipped.reason not in said:
        said.add(skipped.reason)
        logger.warning("skipping %s at %s (the job sent it; later ones are skipped silently)",
                       skipped.reason, skipped.path)

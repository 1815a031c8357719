"""Replaying a job's Rerun packets into ``rerun-sdk``: a spawned viewer, or an ``.rrd`` file.

``rerun-sdk`` is optional (``pip install 'armnet-runtime[view]'``) and imported
only here, when a replay starts. What each entry becomes is decided by
:func:`armnet_client.viewer.entity_logs`; this module only logs it, on two
timelines: ``time`` (the job's clock when the frame was taken) and ``frame``
(the streamer's sequence number, which shows the frames it dropped as gaps).
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any, Optional

from armnet_runtime.rerun import Packet

from .cell_videos import CellVideo
from .errors import RerunMissing
from .viewer import Jpeg, RawImage, Scalar, Skipped, entity_logs, timelines

logger = logging.getLogger(__name__)

#: Where the cell's videos of the job go in the recording: ``armnet-cell/video/<camera>``.
CELL_VIDEO_ENTITY = "armnet-cell/video"
#: The timeline of a video whose info file is missing (not known when it began on the job's clock).
UNPLACED_VIDEO_TIMELINE = "video"

@dataclass(frozen=True)
class Replayed:
    """What a replay logged: packets, entries skipped as malformed, frames the job's streamer dropped."""

    packets: int
    skipped: int
    dropped: int
    #: The cell's videos logged beside the packets (``--cell-video``).
    videos: int = 0


def _rerun() -> Any:
    try:
        import rerun
    except ImportError as exc:
        raise RerunMissing() from exc
    return rerun


def replay(packets: Iterable[Packet], *, app_id: str, save: Optional[str],
           videos: Sequence[CellVideo] = ()) -> Replayed:
    """Log every packet into Rerun: into ``save`` (an ``.rrd``) if given, else a spawned viewer.

    ``videos``: the cell's videos of the job, each logged as a video asset at
    ``armnet-cell/video/<camera>`` with a frame reference per frame on the ``time``
    timeline, so it plays in step with the job's own data. The recording is finalized
    before returning, so the file is complete (and readable by ``rerun.chunk.RrdReader``
    or ``rerun out.rrd``) once this returns.
    """
    rr = _rerun()
    count = skipped = dropped = 0
    said: set[str] = set()
    with rr.RecordingStream(app_id) as rec:
        if save is not None:
            rec.save(save)
        else:
            rec.spawn()
        for video in videos:
            _log_video(rr, rec, video)
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
    return Replayed(count, skipped, dropped, len(videos))


def _log_video(rr: Any, rec: Any, video: CellVideo) -> None:
    """The video as one asset, and a reference to each of its frames at the time it was taken."""
    import numpy as np

    entity = f"{CELL_VIDEO_ENTITY}/{video.camera}"
    asset = rr.AssetVideo(path=str(video.path))
    rec.log(entity, asset, static=True)
    nanos = np.asarray(asset.read_frame_timestamps_nanos(), dtype=np.int64)
    if video.first_frame_at is not None:
        index = rr.TimeColumn("time", timestamp=video.first_frame_at + nanos / 1e9)
    else:  # not known when it began: on a timeline of its own, from its first frame
        index = rr.TimeColumn(UNPLACED_VIDEO_TIMELINE, duration=nanos / 1e9)
    rr.send_columns(entity, indexes=[index], columns=rr.VideoFrameReference.columns_nanos(nanos), recording=rec)


def _say_once(skipped: Skipped, said: set[str]) -> None:
    if skipped.reason not in said:
        said.add(skipped.reason)
        logger.warning("skipping %s at %s (the job sent it; later ones are skipped silently)",
                       skipped.reason, skipped.path)

"""The layout of the cell's record of a job, as stored beside the job's output.

The connector writes the record (its servo trace, each camera's video, the rollouts'
pictures), the node agent stores it under ``armnet-cell/`` of the job's output, and the
client reads it back (``armnet view JOB --cell-video``): the names they share live here
(docs/outputs.md, "The cell's record").
"""

from __future__ import annotations

import json
import math
from pathlib import PurePosixPath

#: The record's folder in a job's stored output (a job's own top-level folder of this name is refused).
CELL_RECORD = "armnet-cell"
#: Below the record: one MP4 per camera the job used, ``<camera>.mp4`` (``<camera>-2.mp4`` after a new size).
VIDEOS = "videos"
#: Below the record: the servo trace's Parquet parts, ``part-000001.parquet`` ...
SERVO_TRACE = "servo-trace"
#: Beside each video, ``<name>.json``: its camera and when its first frame reached the connector
#: (``firstFrameAt``, seconds since the epoch): a frame's time is that plus its presentation time.
VIDEO_INFO_SUFFIX = ".json"
#: The most a video's info file may hold (it is a few fields).
MAX_VIDEO_INFO_BYTES = 4096


def video_info(camera: str, first_frame_at: float, width: int, height: int) -> bytes:
    return json.dumps({"camera": camera, "firstFrameAt": round(first_frame_at, 6),
                       "width": width, "height": height}).encode()


def first_frame_at(info: bytes) -> float | None:
    """When a video's first frame reached the connector, from its info file; None when the file does not say."""
    try:
        value = json.loads(info).get("firstFrameAt")
    except (ValueError, AttributeError):
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        return None
    return float(value) if 0 <= value < 1e11 else None  # seconds since the epoch, not a job's typo


def cell_video_camera(path: str) -> str | None:
    """The camera of a stored path that is one of the record's videos (``armnet-cell/videos/<name>.mp4``), else None."""
    parts = PurePosixPath(path).parts
    if len(parts) == 3 and parts[0] == CELL_RECORD and parts[1] == VIDEOS and parts[2].endswith(".mp4"):
        return parts[2][: -len(".mp4")] or None
    return None

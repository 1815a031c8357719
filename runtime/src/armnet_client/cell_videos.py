"""The cell's videos of a job, fetched back from the store: what ``armnet view JOB --cell-video`` plays.

The connector keeps a video of each camera the job used in the cell's record of the job
(``armnet-cell/videos/<camera>.mp4``, with ``<camera>.json`` saying when its first frame
reached the connector: docs/outputs.md, "The cell's record"); the node agent stores it beside the
job's output. This module picks those files out of the output's manifest, downloads them
(each checked against its SHA-256, as ``armnet artifacts`` does) and says where each
video sits on the job's clock, so a viewer shows it beside the job's own Rerun data.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Optional

from armnet_core.cell_record import (
    MAX_VIDEO_INFO_BYTES,
    VIDEO_INFO_SUFFIX,
    cell_video_camera,
    first_frame_at,
)

from .artifacts import Manifest, OutputStore, download, safe_relative

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class CellVideo:
    """One downloaded video of the cell's record: its camera (the file's name), where it is, when it began."""

    camera: str
    path: Path
    #: When its first frame reached the connector (seconds since the epoch); None: its info file is missing.
    first_frame_at: Optional[float]


def fetch_cell_videos(store: OutputStore, manifest: Manifest, destination: Path) -> list[CellVideo]:
    """Download the record's videos (and their info files) listed in ``manifest`` below ``destination``."""
    videos = [f for f in manifest.files if cell_video_camera(f.path) is not None]
    info_paths = {str(PurePosixPath(f.path).with_suffix(VIDEO_INFO_SUFFIX)) for f in videos}
    infos = [f for f in manifest.files if f.path in info_paths and f.bytes <= MAX_VIDEO_INFO_BYTES]
    download(store, Manifest(tuple(videos + infos), manifest.complete, ()), destination)
    found = []
    for stored in sorted(videos, key=lambda f: f.path):
        local = destination.joinpath(*safe_relative(stored.path).parts)
        info = local.with_suffix(VIDEO_INFO_SUFFIX)
        started = first_frame_at(info.read_bytes()[:MAX_VIDEO_INFO_BYTES]) if info.is_file() else None
        if started is None:
            logger.warning("%s does not say when it began: it plays on a timeline of its own ('video')", stored.path)
        found.append(CellVideo(str(cell_video_camera(stored.path)), local, started))
    return found

"""``armnet view JOB``: replay the job's Rerun packets into a local viewer, an .rrd file, or JSON lines;
``--cell-video`` adds the cell's own video of each camera the job used, from the job's stored output."""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

from armnet_core.api import ArtifactsPhase
from armnet_runtime.rerun import Packet

from ..artifacts import ArtifactsError, open_manifest
from ..cell_videos import CellVideo, fetch_cell_videos
from ..errors import ClientError
from ..viewer import application_id, packet_document, packet_of
from .common import add_cluster_options, client_from, guarded

if TYPE_CHECKING:
    from ..client import Client

EXAMPLES = """
  armnet view pick-7x2k                   # spawn a Rerun viewer and replay (needs armnet-runtime[view])
  armnet view -f pick-7x2k                # ... and keep streaming live packets until the job ends
  armnet view pick-7x2k --save run.rrd    # write a recording instead (open it with: rerun run.rrd)
  armnet view pick-7x2k --dump | head     # decoded packets as JSON lines (no rerun-sdk needed)
  armnet view pick-7x2k --cell-video      # ... with the cell's camera videos, in step (read credentials:
                                          # see armnet artifacts --help)
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("job", help="the RobotJob name")
    parser.add_argument("-f", "--follow", action="store_true", help="keep going until the job ends")
    parser.add_argument("--save", metavar="OUT.rrd", help="write a Rerun recording instead of a viewer")
    parser.add_argument("--dump", action="store_true", help="print decoded packets as JSON lines")
    parser.add_argument("--cell-video", action="store_true",
                        help="also play the cell's video of each camera the job used (from its stored output, "
                             "with your read credentials, as armnet artifacts)")
    parser.add_argument("--endpoint", help="with --cell-video: the object store's URL "
                                           "(default: $ARMNET_ARTIFACTS_ENDPOINT, else AWS S3)")
    add_cluster_options(parser, EXAMPLES)


def cell_videos(client: Client, args: argparse.Namespace, scratch: Path) -> list[CellVideo]:
    """The cell's videos of the job, downloaded to ``scratch`` (Rerun reads each whole when it is logged)."""
    stored = client.read(args.job).status.artifacts
    if stored is None or stored.phase != ArtifactsPhase.UPLOADED or not stored.location or not stored.manifest:
        phase = stored.phase if stored is not None and stored.phase else "not stored yet"
        raise ArtifactsError(f"robotjob {args.job}'s output is {phase}: the cell's videos come with it once the node "
                             "agent stored it (armnet artifacts JOB says when)")
    store, manifest = open_manifest(stored.location, stored.manifest, endpoint_url=args.endpoint)
    return fetch_cell_videos(store, manifest, scratch)


def run(args: argparse.Namespace) -> int:
    def body() -> int:
        client = client_from(args)

        def packets() -> Iterator[Packet]:
            for line in client.logs(args.job, follow=args.follow):
                packet = packet_of(line)
                if packet is not None:
                    yield packet

        if args.dump:
            if args.cell_video:
                raise ClientError("--dump prints the job's packets; the cell's videos play in a viewer or go to "
                                  "--save (or fetch them with: armnet artifacts JOB --download DIR)")
            for packet in packets():
                print(json.dumps(packet_document(packet)), flush=True)
            return 0
        from ..rerun_sink import replay

        with tempfile.TemporaryDirectory(prefix="armnet-view-") as scratch:
            videos = cell_videos(client, args, Path(scratch)) if args.cell_video else []
            done = replay(packets(), app_id=application_id(args.job), save=args.save, videos=videos)
        where = args.save if args.save else "the Rerun viewer"
        print(f"view: {done.packets} packets to {where}; frames the job's streamer dropped: "
              f"{done.dropped}; malformed entries skipped: {done.skipped}"
              + (f"; the cell's videos: {', '.join(v.camera for v in videos) or 'none'}" if args.cell_video else ""),
              file=sys.stderr)
        return 0

    return guarded(body)

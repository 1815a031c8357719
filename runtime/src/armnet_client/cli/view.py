"""``armnet view JOB``: replay the job's Rerun packets into a local viewer, an .rrd file, or JSON lines."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Iterator

from armnet_runtime.rerun import Packet

from ..viewer import application_id, packet_document, packet_of
from .common import add_cluster_options, client_from, guarded

EXAMPLES = """
  armnet view pick-7x2k                   # spawn a Rerun viewer and replay (needs armnet-runtime[view])
  armnet view -f pick-7x2k                # ... and keep streaming live packets until the job ends
  armnet view pick-7x2k --save run.rrd    # write a recording instead (open it with: rerun run.rrd)
  armnet view pick-7x2k --dump | head     # decoded packets as JSON lines (no rerun-sdk needed)
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("job", help="the RobotJob name")
    parser.add_argument("-f", "--follow", action="store_true", help="keep going until the job ends")
    parser.add_argument("--save", metavar="OUT.rrd", help="write a Rerun recording instead of a viewer")
    parser.add_argument("--dump", action="store_true", help="print decoded packets as JSON lines")
    add_cluster_options(parser, EXAMPLES)


def run(args: argparse.Namespace) -> int:
    def body() -> int:
        client = client_from(args)

        def packets() -> Iterator[Packet]:
            for line in client.logs(args.job, follow=args.follow):
                packet = packet_of(line)
                if packet is not None:
                    yield packet

        if args.dump:
            for packet in packets():
                print(json.dumps(packet_document(packet)), flush=True)
            return 0
        from ..rerun_sink import replay

        done = replay(packets(), app_id=application_id(args.job), save=args.save)
        where = args.save if args.save else "the Rerun viewer"
        print(f"view: {done.packets} packets to {where}; frames the job's streamer dropped: "
              f"{done.dropped}; malformed entries skipped: {done.skipped}", file=sys.stderr)
        return 0

    return guarded(body)

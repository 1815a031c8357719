"""``armnet logs [-f] JOB``: the job's output from its first line (JetStream), live with ``-f``."""

from __future__ import annotations

import argparse
import sys

from ..render import utcnow
from .common import add_cluster_options, client_from, guarded
from .printer import LogPrinter, parse_since, tail_batches

EXAMPLES = """
  armnet logs pick-7x2k           # everything the job printed so far, timestamped (UTC)
  armnet logs -f pick-7x2k        # then follow until it ends; progress is one live line
  armnet logs --since 10m --tail 100 -f pick-7x2k
  armnet logs --nats-url nats://nats.armnet:4222 pick-7x2k
without a reachable NATS server the command says so once and follows the job's
status instead: progress, rollout, then the last 16 KiB of output when it ends.
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("job", help="the RobotJob name")
    parser.add_argument("-f", "--follow", action="store_true", help="keep printing until the job ends")
    parser.add_argument("--since", help="only lines newer than a duration (10m, 2h) or an RFC 3339 time")
    parser.add_argument("--tail", type=int, help="start with the last N output lines stored")
    parser.add_argument("--no-timestamps", action="store_true", help="print lines without their time")
    add_cluster_options(parser, EXAMPLES)


def run(args: argparse.Namespace) -> int:
    def body() -> int:
        try:
            since = parse_since(args.since, utcnow()) if args.since else None
        except ValueError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        printer = LogPrinter(sys.stdout, live=sys.stdout.isatty(), timestamps=not args.no_timestamps)
        try:
            batches = client_from(args).log_batches(args.job, follow=args.follow, since=since)
            for lines in tail_batches(batches, args.tail):
                printer.show_all(lines)
        finally:
            printer.close()
        return 0

    return guarded(body)

"""``armnet cancel JOB``: set ``spec.cancel`` (one-way); the operator or the agent stops the job."""

from __future__ import annotations

import argparse

from .common import add_cluster_options, client_from, guarded

EXAMPLES = """
  armnet cancel pick-7x2k         # a queued job ends cancelled at once; a running one within
                                  # the cell's gracePeriodSeconds
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("job", help="the RobotJob name")
    add_cluster_options(parser, EXAMPLES)


def run(args: argparse.Namespace) -> int:
    def body() -> int:
        job = client_from(args).cancel(args.job)
        print(f"robotjob/{job.id} cancel requested (status: {job.status.value})")
        return 0

    return guarded(body)

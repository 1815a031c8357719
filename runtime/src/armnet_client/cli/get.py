"""``armnet get [JOB]``: RobotJobs as a kubectl-like table, or one job as JSON/YAML."""

from __future__ import annotations

import argparse

from ..mapping import job_from_robotjob, view_of
from ..render import dumps, job_document, jobs_table, utcnow
from .common import add_cluster_options, client_from, guarded

EXAMPLES = """
  armnet get                      # the namespace's jobs: status, cell, queue reason #position, age
  armnet get pick-7x2k -o json    # one job as JSON (the SDK's Job plus queue and progress)
  armnet get -o wide -n team-a    # with task, priority, image, progress and rollout
  armnet get -o name              # robotjob/<name> per line, for scripts (and shell completion)
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("job", nargs="?", help="a RobotJob name (default: all in the namespace)")
    parser.add_argument("-o", "--output", choices=("table", "wide", "json", "yaml", "name"), default="table")
    add_cluster_options(parser, EXAMPLES)


def run(args: argparse.Namespace) -> int:
    def body() -> int:
        client = client_from(args)
        jobs = [client.read(args.job)] if args.job else client.list_jobs()
        if args.output in ("json", "yaml"):
            documents = [job_document(job_from_robotjob(j), view_of(j)) for j in jobs]
            print(dumps(documents[0] if args.job else {"items": documents}, args.output))
        elif args.output == "name":
            for job in jobs:
                print(f"robotjob/{job.metadata.name}")
        elif not jobs:
            print(f"No RobotJobs in namespace {client.namespace}.")
        else:
            print(jobs_table([view_of(j) for j in jobs], utcnow(), wide=args.output == "wide"))
        return 0

    return guarded(body)

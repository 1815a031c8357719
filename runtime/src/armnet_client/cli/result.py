"""``armnet result JOB``: the job's ``JobResult``; the exit code says how it ended, for scripts."""

from __future__ import annotations

import argparse

from ..mapping import result_from_robotjob, status_of
from ..render import EXIT_NOT_FINISHED, dumps, result_document, result_exit_code
from .common import add_cluster_options, client_from, guarded

EXIT_ERROR = 3

EXAMPLES = """
  armnet result pick-7x2k                 # JobResult(status=succeeded, exit_code=0) ...
  armnet result pick-7x2k --json | jq .return_value
  armnet result pick-7x2k && echo ok      # exit 0 succeeded, 1 failed/timeout/cancelled,
                                          # 2 not finished yet, 3 could not ask (error)
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("job", help="the RobotJob name")
    parser.add_argument("--json", action="store_true", help="print the JobResult as JSON")
    add_cluster_options(parser, EXAMPLES)


def run(args: argparse.Namespace) -> int:
    def body() -> int:
        job = client_from(args).read(args.job)
        status = status_of(job.status.phase)
        result = result_from_robotjob(job)
        if args.json:
            print(dumps(result_document(result, status), "json"))
        elif result is None:
            print(f"robotjob {args.job} is {status.value}: not finished yet")
        else:
            print(result)
        return result_exit_code(status) if result is not None else EXIT_NOT_FINISHED

    return guarded(body, error_code=EXIT_ERROR)

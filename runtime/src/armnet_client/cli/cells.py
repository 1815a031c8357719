"""``armnet cells``: the Cells, their phase, current job, failing health conditions and heartbeat age."""

from __future__ import annotations

import argparse

from ..render import cell_document, cells_table, dumps, utcnow
from .common import add_cluster_options, client_from, guarded

EXAMPLES = """
  armnet cells                    # NAME PHASE EMBODIMENT TASK JOB FAILING HEARTBEAT
  armnet cells -o json            # {"items": [{"name", "phase", "failingConditions", ...}]}
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("-o", "--output", choices=("table", "wide", "json", "yaml"), default="table")
    add_cluster_options(parser, EXAMPLES)


def run(args: argparse.Namespace) -> int:
    def body() -> int:
        cells = client_from(args).cells()
        if args.output in ("json", "yaml"):
            print(dumps({"items": [cell_document(c) for c in cells]}, args.output))
        elif not cells:
            print("No Cells.")
        else:
            print(cells_table(cells, utcnow(), wide=args.output == "wide"))
        return 0

    return guarded(body)

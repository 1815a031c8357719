"""``armnet quota``: the tenant's standing under its CellQuotas (share, cells held and borrowed, jobs waiting, credits)."""

from __future__ import annotations

import argparse

from ..render import dumps, quota_document, quotas_table
from .common import add_cluster_options, client_from, guarded

EXAMPLES = """
  armnet quota                    # this namespace's CellQuotas: NAME TENANT ... IN-USE BORROWED WAITING CREDITS NOTE
  armnet quota -A -o wide         # every tenant's, with cohort, borrowing limit, weight and decayed usage
  armnet quota -o json            # {"items": [{"name", "tenant", "cellsInUse", "waitingJobs", "credits", ...}]}
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("-A", "--all-tenants", action="store_true",
                        help="every tenant's quotas, not only this namespace's")
    parser.add_argument("-o", "--output", choices=("table", "wide", "json", "yaml"), default="table")
    add_cluster_options(parser, EXAMPLES)


def run(args: argparse.Namespace) -> int:
    def body() -> int:
        client = client_from(args)
        quotas = client.quotas(all_tenants=args.all_tenants)
        if args.output in ("json", "yaml"):
            print(dumps({"items": [quota_document(q) for q in quotas]}, args.output))
        elif not quotas:
            where = "in the cluster" if args.all_tenants else f"for namespace {client.namespace}"
            print(f"No CellQuotas {where}: its jobs are not rationed (priority, then first-come).")
        else:
            print(quotas_table(quotas, wide=args.output == "wide"))
        return 0

    return guarded(body)

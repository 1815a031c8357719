"""``armnet``: one command, subcommands owned by the packages that implement them.

The table below names each subcommand's module lazily, so ``armnet --help`` stays
fast and the operator never imports the agent (or the other way round). A
subcommand module exposes ``add_arguments(parser)`` and ``run(args) -> int``.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence
from dataclasses import dataclass

from armnet_client.cli.commands import COMMANDS as CLIENT_COMMANDS


@dataclass(frozen=True)
class Subcommand:
    name: str
    module: str
    help: str


SUBCOMMANDS: tuple[Subcommand, ...] = (
    Subcommand("run", "armnet_local.cli", "run a job script locally on a simulated cell"),
    Subcommand("sim", "armnet_sim.cli", "run the cell simulator (Feetech bus on a pty, cameras)"),
    Subcommand("connector", "armnet_connector.cli", "run the connector sidecar for one cell"),
    Subcommand("agent", "armnet_node.cli", "run the node agent: heartbeat this host's Cells, run their jobs"),
    Subcommand("operator", "armnet_operator.cli", "run the kopf operator that binds RobotJobs to Cells"),
    Subcommand("fms", "armnet_fms.cli", "serve the cell operator's web page: cells, resets, outcomes, stop"),
    Subcommand("dev", "armnet_cli.dev", "developer helpers: `armnet dev up` starts the local test bed"),
    *(Subcommand(*command) for command in CLIENT_COMMANDS),
    Subcommand("completion", "armnet_cli.completion", "print a bash or zsh completion script for armnet"),
)


def _build_parser(argv: Sequence[str]) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="armnet",
        description="armnet runs robot programs on shared robot cells, the way Kubernetes runs containers on nodes.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    wanted = argv[0] if argv else None
    for command in SUBCOMMANDS:
        child = sub.add_parser(command.name, help=command.help, description=command.help)
        if command.name == wanted:
            # Only the chosen subcommand's module is imported: its dependencies
            # (kopf, LeRobot, docker) are heavy and irrelevant to the others.
            module = importlib.import_module(command.module)
            module.add_arguments(child)
            child.set_defaults(_module=module)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args_list = list(sys.argv[1:] if argv is None else argv)
    parser = _build_parser(args_list)
    args = parser.parse_args(args_list)
    module = getattr(args, "_module", None)
    if module is None:
        parser.print_help()
        return 0 if not args_list else 2
    return int(module.run(args) or 0)


if __name__ == "__main__":
    raise SystemExit(main())

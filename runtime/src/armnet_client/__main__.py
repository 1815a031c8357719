"""``python -m armnet_client <command>``: the client's commands without the platform's ``armnet``.

A customer who installed only ``armnet-runtime[client]`` has no ``armnet``
console script (that ships with the platform); this entry point runs the same
subcommand modules (``cli.commands.COMMANDS``), so both behave identically.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence
from typing import Optional

from .cli.commands import COMMANDS


def main(argv: Optional[Sequence[str]] = None) -> int:
    args_list = list(sys.argv[1:] if argv is None else argv)
    parser = argparse.ArgumentParser(prog="python -m armnet_client",
                                     description="armnet's customer client (the `armnet` job commands).")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, module_name, help_text in COMMANDS:
        child = sub.add_parser(name, help=help_text, description=help_text)
        if args_list and args_list[0] == name:
            module = importlib.import_module(module_name)
            module.add_arguments(child)
            child.set_defaults(_module=module)
    args = parser.parse_args(args_list)
    chosen = getattr(args, "_module", None)
    if chosen is None:
        parser.print_help()
        return 0 if not args_list else 2
    return int(chosen.run(args) or 0)


if __name__ == "__main__":
    raise SystemExit(main())

"""The ``armnet`` subcommands of the client: submit, get, cells, result, cancel, logs.

Each module has ``add_arguments(parser)`` and ``run(args) -> int``, the
contract of ``armnet_cli.main``; :data:`commands.COMMANDS` lists them.
"""

"""The ``armnet`` command line: one entry point whose subcommands live in the packages that own them."""

#: The modules other packages import (none: it is the top of the stack).
__all__: list[str] = []

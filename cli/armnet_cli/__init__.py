"""The ``armnet`` command line: one entry point whose subcommands live in the packages that own them."""

"""The `holo` command line: subcommands live in `holo/cmd_*.py` and import heavy modules lazily."""

"""Command line: ``dimacq SUBCOMMAND``; each subcommand lives in :mod:`dimacq.cli.commands`."""

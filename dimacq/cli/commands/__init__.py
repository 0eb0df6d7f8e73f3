"""One module per subcommand.

Each module defines ``register(subparsers) -> None`` that adds its parser and sets
``func=handler`` with ``handler(args) -> int``. :func:`dimacq.cli.main.main` discovers them.
"""

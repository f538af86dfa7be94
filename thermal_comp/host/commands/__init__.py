"""One module per `host` subcommand.

Each module defines ``NAME`` (the subcommand), ``HELP`` (one line), ``register(parser)``
(adds its arguments to an argparse sub-parser) and ``run(args) -> int`` (exit code).
``host.cli`` discovers them, so adding a command is adding a file.
"""

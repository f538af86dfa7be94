"""The `host` command line: discovers subcommands in host.commands and maps errors to exit codes.

The library raises the project's own errors (``contract.errors.InputError`` and its subclasses,
with messages that name the file, line, column, term or limit); this is the only place that
turns them into a message on stderr and an exit code: 0 ok, 1 a check failed, 2 bad input or
usage. A file the system cannot open (``OSError``) is reported the same way; anything else is a
bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys

import host.commands
from contract import __version__
from contract.errors import InputError


def _command_modules() -> list:
    mods = []
    for info in sorted(pkgutil.iter_modules(host.commands.__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        mods.append(importlib.import_module(f"host.commands.{info.name}"))
    return mods


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="host", description="Thermal-error compensation: select sensors, fit, "
        "evaluate, generate firmware headers, simulate and report.")
    parser.add_argument("--version", action="version", version=f"host {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for mod in _command_modules():
        p = sub.add_parser(mod.NAME, help=mod.HELP, description=mod.HELP)
        mod.register(p)
        p.set_defaults(_run=mod.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except InputError as exc:
        print(f"host {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"host {args.command}: error: {exc.filename or ''}: {exc.strerror or exc}",
              file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"host {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    raise SystemExit(main())

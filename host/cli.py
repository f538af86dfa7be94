"""The `host` command line: discovers subcommands in host.commands and maps errors to exit codes.

The library raises the project's own errors (``contract.errors.InputError`` and its subclasses,
with messages that name the file, line, column, term or limit); this is the only place that
turns them into a message on stderr and an exit code: 0 ok, 1 a check failed, 2 bad input or
usage. A file the system cannot open (``OSError``) is reported the same way; anything else is a
bug and keeps its traceback. A command whose optional dependency is not installed (a
training-only install: ``pip install thermal-comp``) says which extra brings it.

``-q/--quiet`` (before or after the command) silences the progress bars on stderr; results and
errors are still printed.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys

import host.commands
from contract import __version__
from contract.errors import InputError
from host.progress import set_quiet

# optional dependency (import name) -> the extra that installs it (pyproject.toml)
EXTRAS = {"matplotlib": "report", "serial": "monitor", "sklearn": "sklearn", "paho": "fleet",
          "psycopg": "fleet"}


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
    parser.add_argument("-q", "--quiet", action="store_true",
                        help="no progress bars on stderr (results and errors still print)")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for mod in _command_modules():
        p = sub.add_parser(mod.NAME, help=mod.HELP, description=mod.HELP)
        mod.register(p)
        if not any("--quiet" in a.option_strings for a in p._actions):
            p.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS,
                           help="no progress bars on stderr (results and errors still print)")
        p.set_defaults(_run=mod.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    set_quiet(getattr(args, "quiet", False))
    try:
        return int(args._run(args) or 0)
    except ModuleNotFoundError as exc:
        extra = EXTRAS.get((exc.name or "").split(".")[0])
        if extra is None:
            raise
        print(f"host {args.command}: error: needs the Python package '{exc.name}', not "
              f"installed: pip install 'thermal-comp[{extra}]' (or [all])", file=sys.stderr)
        return 2
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

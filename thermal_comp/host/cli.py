"""The `host` command line: discovers subcommands in host.commands and maps errors to exit codes.

The library raises the project's own errors (``contract.errors.InputError`` and its subclasses,
with messages that name the file, line, column, term or limit); this is the only place that
turns them into a message on stderr and an exit code: 0 ok, 1 a check failed, 2 bad input or
usage. A file the system cannot open (``OSError``) is reported the same way; anything else is a
bug and keeps its traceback. A command whose optional dependency is not installed (a
training-only install: ``pip install thermal-comp``) says which extra brings it.

A reader that stops early (``host simulate ... | head -1``) ends the command quietly, as it
ends a Unix tool: exit status 141 (128 + SIGPIPE, what a shell reports for ``yes | head -1``)
and nothing on stderr. A broken pipe that is not standard output (a socket, a serial line)
is an error like any other ``OSError``.

``-q/--quiet`` (before or after the command) silences the progress bars on stderr; results and
errors are still printed.
"""

from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import select
import sys

import thermal_comp.host.commands as commands
from thermal_comp.contract import __version__
from thermal_comp.contract.errors import InputError
from thermal_comp.host.progress import set_quiet

# optional dependency (import name) -> the extra that installs it (pyproject.toml)
EXTRAS = {"matplotlib": "report", "serial": "monitor", "sklearn": "sklearn", "paho": "fleet",
          "psycopg": "fleet"}

EXIT_BROKEN_PIPE = 128 + 13  # what a shell reports for a tool SIGPIPE ended


def _stdout_gone() -> bool:
    """Whether standard output is a pipe whose reader has gone (poll reports POLLERR on the
    write end of a pipe nobody reads any more)."""
    try:
        poller = select.poll()
        poller.register(sys.stdout.fileno(), select.POLLOUT)
        return any(ev & select.POLLERR for _, ev in poller.poll(0))
    except (AttributeError, OSError, ValueError):  # no poll(), no real stdout
        return False


def _silence_stdout() -> None:
    """Point standard output at /dev/null, so the interpreter's flush at exit does not raise
    again (the Python documentation's recipe for SIGPIPE, signal module notes)."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)


def _command_modules() -> list:
    mods = []
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        mods.append(importlib.import_module(f"{commands.__name__}.{info.name}"))
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
        code = int(args._run(args) or 0)
        sys.stdout.flush()  # a reader gone shows here, not in the interpreter's exit
        return code
    except BrokenPipeError as exc:
        if not _stdout_gone():
            print(f"host {args.command}: error: {exc.filename or ''}: {exc.strerror or exc}",
                  file=sys.stderr)
            return 2
        _silence_stdout()
        return EXIT_BROKEN_PIPE
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

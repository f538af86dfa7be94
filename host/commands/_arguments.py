"""Arguments several subcommands share (a module, not a command: its name starts with _)."""

from __future__ import annotations

import argparse

from host.train import DEFAULT_REFERENCE

REFERENCE_HELP = ("what zero drift means: 'start' = the change since each run's start (ISO "
                  "230-3: probes zeroed when the test starts; the box: since power-up or ZERO), "
                  "'none' = absolute values against one datum (a continuous recording)")


def add_reference_argument(parser: argparse.ArgumentParser, *, training: bool) -> None:
    """``--reference start|none``: training defaults to start, judging to the model's own."""
    default = DEFAULT_REFERENCE if training else None
    tail = f" (default {DEFAULT_REFERENCE})" if training else " (default: the model's)"
    parser.add_argument("--reference", choices=("start", "none"), default=default,
                        help=REFERENCE_HELP + tail)

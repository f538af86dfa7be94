"""Arguments several subcommands share (a module, not a command: its name starts with _)."""

from __future__ import annotations

import argparse

from thermal_comp.host.train import DEFAULT_REFERENCE

REFERENCE_HELP = ("what zero drift means: 'start' = the change since each run's start (ISO "
                  "230-3: probes zeroed when the test starts; the box: since power-up or ZERO), "
                  "'none' = absolute values against one datum (a continuous recording)")


def add_reference_argument(parser: argparse.ArgumentParser, *, training: bool) -> None:
    """``--reference start|none``: training defaults to start, judging to the model's own."""
    default = DEFAULT_REFERENCE if training else None
    tail = f" (default {DEFAULT_REFERENCE})" if training else " (default: the model's)"
    parser.add_argument("--reference", choices=("start", "none"), default=default,
                        help=REFERENCE_HELP + tail)


# A thermal test (ISO 230-3) runs hours to days; a month is far beyond any of them, and the
# simulator's arrays grow with it (--hours 1e9 asked numpy for 447 GiB).
MAX_PHASE_HOURS = 720.0
# numpy's legacy RandomState takes seeds 0 .. 2**32 - 1; a negative one was a traceback
MAX_SEED = 2**32 - 1


def seed_arg(text: str) -> int:
    """``--seed``: a whole number 0 .. 2**32 - 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if not 0 <= value <= MAX_SEED:
        raise argparse.ArgumentTypeError(f"{value} must be between 0 and {MAX_SEED}")
    return value


def hours_arg(text: str) -> float:
    """``--hours``/``--cool-hours``: a finite number of hours, 0 .. MAX_PHASE_HOURS."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of hours") from None
    if not 0.0 <= value <= MAX_PHASE_HOURS:  # also refuses nan and inf
        raise argparse.ArgumentTypeError(
            f"{text} h must be between 0 and {MAX_PHASE_HOURS:g} h (30 days: a thermal test "
            "runs hours to days)")
    return value

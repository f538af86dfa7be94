"""Argument types and options shared by the commands that read runs (not a command itself).

Validated at parse time, so a bad value is refused by argparse with the option named
(``host train: error: argument --fill-gaps: ...``, exit 2) before any file is read.
"""

from __future__ import annotations

import argparse


def non_negative_int(text: str) -> int:
    """argparse type: an integer >= 0."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number of samples, got {text!r}"
                                         ) from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be 0 (reject every empty cell) or a positive "
                                         f"number of samples, got {value}")
    return value


def add_fill_gaps(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--fill-gaps", type=non_negative_int, default=0, metavar="N",
                        help="interpolate interior gaps of at most N samples (default 0: "
                        "reject every empty cell)")

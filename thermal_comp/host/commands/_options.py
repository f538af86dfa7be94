"""Argument types and options shared by the commands that read runs (not a command itself).

Validated at parse time, so a bad value is refused by argparse with the option named
(``host train: error: argument --fill-gaps: ...``, exit 2) before any file is read.
"""

from __future__ import annotations

import argparse

from thermal_comp.host.io import DISP_UNITS, TEMP_UNITS, TIME_UNITS, CsvFormat


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
    """--fill-gaps N, and the run file format (--sep, --decimal, --time-col)."""
    add_format_arguments(parser)
    parser.add_argument("--fill-gaps", type=non_negative_int, default=0, metavar="N",
                        help="interpolate interior gaps of at most N samples: empty cells, "
                        "and rows missing from the time grid (default 0: reject them)")


_SEPARATORS = {"tab": "\t", "\\t": "\t", "comma": ",", "semicolon": ";", "space": " "}


def separator(text: str) -> str:
    """argparse type: one delimiter character, or tab / comma / semicolon / space."""
    sep = _SEPARATORS.get(text.lower(), text)
    if len(sep) != 1 or sep in "\"\r\n" or sep.isalnum():
        raise argparse.ArgumentTypeError(f"expected one character such as ',' ';' or 'tab', "
                                         f"got {text!r}")
    return sep


def add_format_arguments(parser: argparse.ArgumentParser) -> None:
    """--sep, --decimal, --time-col: how the run files are written (default: sniffed)."""
    group = parser.add_argument_group(
        "run file format", "data loggers write ';', decimal commas and ISO timestamps; each is "
        "sniffed from the file unless given")
    group.add_argument("--sep", type=separator, default=None, metavar="CHAR",
                       help="column delimiter: ',' ';' 'tab' ... (default: sniffed from the "
                       "header line)")
    group.add_argument("--decimal", choices=(".", ","), default=None,
                       help="decimal mark (default '.' with ',' as delimiter, else ',' and '.' "
                       "are both read)")
    group.add_argument("--time-col", default=None, metavar="COL",
                       help="time column: seconds or ISO 8601 timestamps such as "
                       "2024-03-01T12:00:00 (default time_s, or the one column of timestamps)")
    units = parser.add_argument_group(
        "units", "a run is read in seconds, degC and micrometres; one that looks written in "
        "another unit (minutes, ms, degF, kelvin, mm, nm) is refused, saying which: give its "
        "unit here and it is converted on reading (or give the default unit to say the data "
        "really is in it)")
    units.add_argument("--time-unit", choices=tuple(TIME_UNITS), default=None,
                       help="unit of a numeric time column (default s)")
    units.add_argument("--temp-unit", choices=TEMP_UNITS, default=None,
                       help="unit of the temperature columns: C, F or K (default C)")
    units.add_argument("--disp-unit", choices=tuple(DISP_UNITS), default=None,
                       help="unit of the displacement (and gap-probe) columns: um, mm or nm "
                       "(default um)")


def csv_format(args: argparse.Namespace) -> CsvFormat:
    """The CsvFormat the parsed --sep/--decimal/--time-col ask for (InputError if they clash)."""
    return CsvFormat(args.sep, args.decimal, args.time_col,
                     getattr(args, "time_unit", None), getattr(args, "temp_unit", None),
                     getattr(args, "disp_unit", None))

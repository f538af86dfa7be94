"""How a run file is written (delimiter, decimal mark, time column, units) and the sniffing
of what is not given: data loggers write ``;``, decimal commas and timestamps, and a user
should not have to say what the header line already shows."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from thermal_comp.contract.errors import InputError
from thermal_comp.contract.textfile import read_utf8
from thermal_comp.host.io.format_error import RunFormatError

DELIMITERS = {",": "comma", ";": "semicolon", "\t": "tab"}
# Units a run's columns may be written in (CsvFormat), each with its conversion to the
# project's: seconds, degC, micrometres.
TIME_UNITS = {"s": 1.0, "min": 60.0, "h": 3600.0, "ms": 0.001}
TEMP_UNITS = ("C", "F", "K")
DISP_UNITS = {"um": 1.0, "mm": 1000.0, "nm": 0.001}


def to_celsius(values: np.ndarray, unit: str | None) -> np.ndarray:
    """Temperatures in ``unit`` (TEMP_UNITS; None: degC) as degC, the unit the box reads."""
    if unit == "F":
        return (values - 32.0) / 1.8
    if unit == "K":
        return values - 273.15
    return values


@dataclass(frozen=True)
class CsvFormat:
    """How a run file is written (data loggers write ``;``, decimal commas and ISO
    timestamps). Every field left ``None`` is sniffed from the file:

    - ``sep``: the delimiter; sniffed from the header line (``,``, ``;`` or tab, the most
      frequent of them);
    - ``decimal``: ``.`` when the delimiter is ``,``; otherwise a decimal comma (``20,5``) and a
      point (``20.5``) are both read, a cell with both (``1.234,5``) is refused;
    - ``time_col``: ``time_s``, else the one column whose first cell is an ISO 8601 timestamp
      (a column of numbers is never guessed to be time: they could be minutes). Its cells are
      seconds or ISO 8601 timestamps
      (``2024-03-01T12:00:00``, ``2024-03-01 12:00:00,5``, with or without a UTC offset), which
      become seconds since the first sample; the column is called ``time_s`` from then on.
    - ``time_unit``, ``temp_unit``, ``disp_unit``: the units the columns are written in,
      converted on reading to seconds, degC and micrometres (``TIME_UNITS``, ``TEMP_UNITS``,
      ``DISP_UNITS``). Left ``None``, they are those, and a run that looks written in another
      unit (minutes, ms; degF, kelvin; mm, nm) is refused with what it looks like and what to
      pass; given, the columns are read in that unit without a guess.
    """

    sep: str | None = None
    decimal: str | None = None
    time_col: str | None = None
    time_unit: str | None = None
    temp_unit: str | None = None
    disp_unit: str | None = None

    def __post_init__(self) -> None:
        sep, decimal = self.sep, self.decimal
        if sep is not None and (len(sep) != 1 or sep in "\"\r\n" or sep.isalnum()):
            raise InputError(f"--sep must be one character such as ',' ';' or a tab, got {sep!r}")
        if decimal not in (None, ".", ","):
            raise InputError(f"--decimal must be '.' or ',', got {decimal!r}")
        if decimal == "," and sep == ",":
            raise InputError("--decimal ',' needs a --sep other than ',' (e.g. --sep ';')")
        for option, value, known in (("--time-unit", self.time_unit, TIME_UNITS),
                                     ("--temp-unit", self.temp_unit, TEMP_UNITS),
                                     ("--disp-unit", self.disp_unit, DISP_UNITS)):
            if value is not None and value not in known:
                raise InputError(f"{option} must be one of {', '.join(known)}, got {value!r}")


@dataclass(frozen=True)
class Source:
    """A decoded run file and the format it is read with."""

    path: Path
    text: str
    sep: str
    decimal: str
    time_col: str | None  # as given (--time-col); None: time_s or sniffed
    time_unit: str | None = None  # as given (--time-unit); None: seconds


def _delimiter_name(d: str) -> str:
    return f"{DELIMITERS.get(d, 'the character')} ({d!r})"


def read_source(path: Path, fmt: CsvFormat | None) -> Source:
    """The file decoded, with the delimiter the header line shows unless ``fmt`` gives one
    (a given one the header does not use is refused: the whole row would be one column)."""
    fmt = fmt or CsvFormat()
    text = read_utf8(path)
    if text.startswith("\ufeff"):
        text = text[1:]
    first = text.split("\n", 1)[0].rstrip("\r")
    counts = {d: first.count(d) for d in DELIMITERS}
    likely = max(counts, key=lambda d: counts[d])
    sep = fmt.sep
    if sep is None:
        sep = likely if counts[likely] else ","
    elif sep not in first and counts[likely]:
        raise RunFormatError(path, f"with --sep {sep!r} the header is one column "
                             f"({first[:60]!r}); the file is {_delimiter_name(likely)}-"
                             f"delimited: pass --sep {likely!r} or leave --sep out to sniff it",
                             line=1)
    decimal = fmt.decimal or ("." if sep == "," else ",")
    return Source(path, text, sep, decimal, fmt.time_col, fmt.time_unit)

"""One column's cells as numbers or timestamps, the first bad cell named by line and column:
a logger's dialect (decimal commas, dd.mm.yyyy dates) is read, a cell that is neither is
refused with what it looks like."""

from __future__ import annotations

import math
import re
from datetime import datetime

import numpy as np

from thermal_comp.host.io.csv_format import Source
from thermal_comp.host.io.format_error import RunFormatError

# A date written day.month.year (dd.mm.yyyy, as German and many European loggers write it),
# or with '/' or '-' (dd/mm/yyyy or mm/dd/yyyy: which one the column's dates must tell), with
# an optional time of day.
_DATE = re.compile(r"^(\d{1,2})([./-])(\d{1,2})\2(\d{4})"
                   r"(?:[ T](\d{1,2}):(\d{2})(?::(\d{2})(?:[.,](\d{1,6}))?)?)?$")


def _number(src: Source, text: str, line: int, column: str) -> float:
    """One cell as a number (empty or 'nan': NaN), or refused with what it looks like."""
    if text == "" or text.lower() in ("nan", "na", "null"):
        return math.nan
    cell = text
    if src.decimal == "," and "," in cell:
        if "." in cell:
            raise RunFormatError(src.path, f"not a number: {text!r} (both '.' and ',': a "
                                 "thousands separator? write plain numbers)", line=line,
                                 column=column)
        cell = cell.replace(",", ".")
    try:
        value = float(cell)
    except ValueError:
        hint = ""
        if _DATE.match(text):
            hint = (f" (a date and time, in a column that is not the time column: name it with "
                    f"--time-col '{column}', or leave the column out)")
        elif "," in text and src.decimal == ".":
            hint = " (a decimal comma? pass --decimal ',' with --sep ';')"
        raise RunFormatError(src.path, f"not a number: {text!r}{hint}", line=line,
                             column=column) from None
    if math.isinf(value):
        raise RunFormatError(src.path, f"infinite value: {text!r}", line=line, column=column)
    return value


def column_numbers(src: Source, cells: list[str], lines: list[int], column: str) -> np.ndarray:
    """A column of cells as floats: numpy's parser when every cell is a plain finite number,
    else cell by cell (empty/'nan' cells NaN; the first bad cell named)."""
    try:
        plain = [c.replace(",", ".") for c in cells] if src.decimal == "," else cells
        if not any("." in c and "," in c for c in cells):
            values = np.array(plain, dtype=float)
            if np.isfinite(values).all():
                return values
    except ValueError:
        pass
    return np.array([_number(src, c, line, column) for c, line in zip(cells, lines, strict=True)],
                    dtype=float)


def _date_order(src: Source, cells: list[str], lines: list[int], column: str) -> str:
    """"dmy" or "mdy" for a column's non-ISO dates: dots are day-first; with '/' or '-' a
    first field above 12 says day-first, a second above 12 month-first; if none does, the
    column is refused (4/5/2026 is 4 May or 5 April)."""
    found = [(m, line) for c, line in zip(cells, lines, strict=True) if (m := _DATE.match(c))]
    if not found:
        return "dmy"
    m, line = found[0]
    if m.group(2) == ".":
        return "dmy"
    if any(int(x.group(1)) > 12 for x, _ in found):
        return "dmy"
    if any(int(x.group(3)) > 12 for x, _ in found):
        return "mdy"
    raise RunFormatError(src.path, f"the dates ({m.group(0)!r}) can be read day-first or "
                         "month-first and no date in the column tells which (no day above 12): "
                         "write them as ISO 8601, e.g. 2024-03-01 12:00:00", line=line,
                         column=column)


def _stamp(text: str, order: str) -> datetime:
    """An ISO 8601 timestamp or a dd.mm.yyyy (``order``: "dmy"/"mdy") one; ValueError if
    neither."""
    try:
        return datetime.fromisoformat(text)
    except ValueError:
        pass
    m = _DATE.match(text)
    if m is None:
        raise ValueError(text)
    a, _, b, year, hh, mm, ss, frac = m.groups()
    day, month = (int(a), int(b)) if order == "dmy" else (int(b), int(a))
    return datetime(int(year), month, day, int(hh or 0), int(mm or 0), int(ss or 0),
                    int((frac or "0").ljust(6, "0")[:6]))


def column_timestamps(src: Source, cells: list[str], lines: list[int], column: str) -> np.ndarray:
    """ISO 8601 or day-first (dd.mm.yyyy HH:MM:SS) timestamps -> seconds since the first one
    (empty cells NaN)."""
    out = np.full(len(cells), math.nan)
    t0: datetime | None = None
    order = _date_order(src, cells, lines, column)
    for i, (text, line) in enumerate(zip(cells, lines, strict=True)):
        if not text:
            continue
        try:
            stamp = _stamp(text, order)
        except ValueError:
            raise RunFormatError(src.path, f"not a number of seconds nor a timestamp: "
                                 f"{text!r} (e.g. 2024-03-01T12:00:00, 2024-03-01 12:00:00,5 "
                                 "or 01.03.2024 12:00:00)", line=line, column=column) from None
        if t0 is None:
            t0 = stamp
        elif (stamp.tzinfo is None) != (t0.tzinfo is None):
            raise RunFormatError(src.path, f"timestamp {text!r} mixes timestamps with and "
                                 "without a UTC offset", line=line, column=column)
        out[i] = (stamp - t0).total_seconds()
    return out


def is_timestamp(text: str) -> bool:
    """Whether a cell is a date and time (ISO 8601 or dd.mm.yyyy), not a number."""
    try:
        float(text.replace(",", "."))
        return False
    except ValueError:
        pass
    try:
        datetime.fromisoformat(text)
        return True
    except ValueError:
        return _DATE.match(text) is not None

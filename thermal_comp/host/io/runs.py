"""Load thermal test runs (CSV) into arrays, rejecting bad input with file, line and column.

Over 400 lines: every refusal of a run file names its cell, and they live with the reader.

A run is a CSV file with a header row: ``time_s`` (strictly increasing seconds at one fixed
period), temperature columns in degC, optional auxiliary columns (e.g. ``spindle_rpm``) and one
or more displacement columns in micrometres. Which column plays which role is decided by the
caller (``--target``, ``--sensors``, ``--aux``), never guessed from the values.

Data loggers' dialects are read as well (``CsvFormat``: ``;`` or tab delimiters, decimal
commas, ISO 8601 timestamps as time), sniffed unless given. What cannot be a thermal test run
is refused, naming the cell: a temperature outside its channel's valid range, a
displacement or aux value beyond the box's int32, time in milliseconds, a gap in time (the
filters would restart: cut the run there) and jitter (named with the period it implies).
"""

from __future__ import annotations

import csv
import difflib
import fnmatch
import io
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

import numpy as np

from thermal_comp.contract.box import CHANNEL_MAX_C, CHANNEL_MIN_C
from thermal_comp.contract.errors import InputError, MissingColumnError
from thermal_comp.contract.fixed_point import INT32_MAX
from thermal_comp.contract.textfile import read_utf8
from thermal_comp.contract.tilt import Tilt, probe_columns

TIME_COLUMN = "time_s"


class RunFormatError(InputError):
    """A run file cannot be used; the message names file, line and column."""

    def __init__(self, path: str | Path, message: str, line: int | None = None,
                 column: str | None = None) -> None:
        where = str(path)
        if line is not None:
            where += f", line {line}"
        if column is not None:
            where += f", column '{column}'"
        super().__init__(f"{where}: {message}")
        self.path = str(path)
        self.line = line
        self.column = column


@dataclass
class Run:
    """One thermal test run, columns already split by role."""

    path: str
    time_s: np.ndarray
    sensor_names: list[str]
    temperatures: np.ndarray  # (n_samples, n_sensors), degC
    target_names: list[str]
    displacements: np.ndarray  # (n_samples, n_targets), um
    aux_names: list[str] = field(default_factory=list)
    aux: np.ndarray | None = None  # (n_samples, n_aux)
    filled_cells: int = 0
    piece: bool = False  # cut out of one run for validation (slice): the same day as the rest

    @property
    def n_samples(self) -> int:
        return int(self.time_s.shape[0])

    @property
    def name(self) -> str:
        return Path(self.path).stem

    @property
    def period_s(self) -> float:
        """Median sample period; models with dynamic terms assume this fixed period."""
        return float(np.median(np.diff(self.time_s)))

    def column(self, name: str) -> np.ndarray:
        """Any column by name (sensor, target, aux or time_s)."""
        if name == TIME_COLUMN:
            return self.time_s
        for names, data in ((self.sensor_names, self.temperatures),
                            (self.target_names, self.displacements),
                            (self.aux_names, self.aux)):
            if name in names and data is not None:
                return data[:, names.index(name)]
        raise MissingColumnError(f"{self.path}: no column '{name}'")

    def columns(self) -> dict[str, np.ndarray]:
        """All columns by name, for term evaluation (see contract.terms)."""
        out = {TIME_COLUMN: self.time_s}
        out.update({n: self.temperatures[:, i] for i, n in enumerate(self.sensor_names)})
        out.update({n: self.displacements[:, i] for i, n in enumerate(self.target_names)})
        if self.aux is not None:
            out.update({n: self.aux[:, i] for i, n in enumerate(self.aux_names)})
        return out

    def target(self, name: str) -> np.ndarray:
        return self.displacements[:, self.target_names.index(name)]

    def every(self, step: int) -> Run:
        """Every ``step``-th sample (its period ``step`` times longer), for a quick screening."""
        if step <= 1:
            return self
        return Run(self.path + f"[::{step}]", self.time_s[::step], list(self.sensor_names),
                   self.temperatures[::step], list(self.target_names),
                   self.displacements[::step], list(self.aux_names),
                   None if self.aux is None else self.aux[::step], piece=self.piece)

    def slice(self, start: int, stop: int) -> Run:
        """A contiguous part of the run (for time-blocked validation)."""
        return Run(self.path + f"[{start}:{stop}]", self.time_s[start:stop],
                   list(self.sensor_names), self.temperatures[start:stop], list(self.target_names),
                   self.displacements[start:stop], list(self.aux_names),
                   None if self.aux is None else self.aux[start:stop], piece=True)


DELIMITERS = {",": "comma", ";": "semicolon", "\t": "tab"}
# Units a run's columns may be written in (CsvFormat), each with its conversion to the
# project's: seconds, degC, micrometres.
TIME_UNITS = {"s": 1.0, "min": 60.0, "h": 3600.0, "ms": 0.001}
TEMP_UNITS = ("C", "F", "K")
DISP_UNITS = {"um": 1.0, "mm": 1000.0, "nm": 0.001}


def to_celsius(values: np.ndarray, unit: str | None) -> np.ndarray:
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
class _Source:
    """A decoded run file and the format it is read with."""

    path: Path
    text: str
    sep: str
    decimal: str
    time_col: str | None  # as given (--time-col); None: time_s or sniffed
    time_unit: str | None = None  # as given (--time-unit); None: seconds


def _delimiter_name(d: str) -> str:
    return f"{DELIMITERS.get(d, 'the character')} ({d!r})"


def _source(path: Path, fmt: CsvFormat | None) -> _Source:
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
    return _Source(path, text, sep, decimal, fmt.time_col, fmt.time_unit)


_POW10 = 10.0 ** np.arange(16)
_PLAIN_DIGITS = 15  # up to 15 digits a decimal's integer is exact, and so is its quotient
_CHUNK_BYTES = 1 << 18  # rows parsed together: their per-character arrays stay in cache


def _plain_numbers(text: str, start: int, sep: str, n_cols: int, n_rows: int | None = None
                   ) -> np.ndarray | None:
    """The rows of ``text`` from character ``start`` on (one a line; ``n_rows`` of them if
    given) as numbers, vectorised: what np.loadtxt reads from them,
    bit for bit, or None (then np.loadtxt, whose C parser converts every cell on its own,
    ~4x this). Each cell of at most 15 digits, a sign and a point is its digits' integer
    (exact below 2**53) divided by a power of ten (exact): one correctly rounded division,
    the same double as the decimal's correct rounding that the C parser returns. A cell with
    an exponent goes through float(); anything else (a blank, a letter, more digits, a
    short row) returns None."""
    try:
        raw = text.encode("ascii")  # ASCII: a character's index is its byte's
    except UnicodeEncodeError:
        return None
    if not raw.endswith(b"\n"):
        raw += b"\n"
    if start >= len(raw):
        return None
    ends = np.flatnonzero(np.frombuffer(raw, dtype=np.uint8, offset=start) == 10) + start
    if n_rows is None:
        n_rows = ends.size
    if ends.size != n_rows or not n_rows or len(sep) != 1 or n_cols < 1:
        return None
    out = np.empty((n_rows, n_cols))
    flat = out.reshape(-1)
    step = max(1, _CHUNK_BYTES * n_rows // (len(raw) - start))
    for r0 in range(0, n_rows, step):
        r1 = min(n_rows, r0 + step)
        a, b = (start if r0 == 0 else int(ends[r0 - 1]) + 1), int(ends[r1 - 1]) + 1
        cells = _plain_cells(raw[a:b], ord(sep), n_cols, r1 - r0)
        if cells is None:
            return None
        flat[r0 * n_cols:r1 * n_cols] = cells
    return out


def _plain_cells(raw: bytes, sep: int, n_cols: int, n_rows: int) -> np.ndarray | None:
    """The cells of ``raw`` (whole lines, each ending in a newline); see _plain_numbers."""
    c = np.frombuffer(raw, dtype=np.uint8)
    is_sep = (c == sep) | (c == 10)
    ends = np.flatnonzero(is_sep)
    if ends.size != n_rows * n_cols or not (c[ends[n_cols - 1::n_cols]] == 10).all():
        return None  # a row of another length
    digit = c - np.uint8(48)
    is_digit = digit < 10
    dots = np.flatnonzero(c == 46)
    minus = np.flatnonzero(c == 45)
    other = np.flatnonzero((c == 101) | (c == 69) | (c == 43))  # e E +: float() reads them
    if (int(np.count_nonzero(is_digit)) + ends.size + dots.size + minus.size + other.size
            != c.size):
        return None  # another character: a blank, a letter, a quote
    cell_of = np.cumsum(is_sep, dtype=np.int64)
    cell_of -= is_sep
    seen = np.cumsum(is_digit, dtype=np.int64)
    upto = seen[ends]  # digits up to each cell's end
    count = np.diff(upto, prepend=0)
    special = np.zeros(ends.size, dtype=bool)
    special[cell_of[other]] = True
    if other.size:
        dots = dots[~special[cell_of[dots]]]
        minus = minus[~special[cell_of[minus]]]
    starts = np.empty_like(ends)
    starts[0] = 0
    starts[1:] = ends[:-1] + 1
    if minus.size and not (starts[cell_of[minus]] == minus).all():
        return None  # a sign inside a number
    plain = count[~special] if other.size else count
    if plain.size and (plain.min() < 1 or plain.max() > _PLAIN_DIGITS):
        return None  # an empty cell, a lone sign or point, or too many digits
    pos = np.flatnonzero(is_digit)
    cells = cell_of[pos]
    if other.size:
        keep = ~special[cells]
        pos, cells = pos[keep], cells[keep]
    # a cell's integer: its digits times 10 ** (digits after each); the sums are exact
    mant = np.bincount(cells, weights=digit[pos] * _POW10[upto[cells] - seen[pos]],
                       minlength=ends.size)
    scale = np.ones(ends.size)
    if dots.size:
        dot_cells = cell_of[dots]
        if (np.diff(dot_cells) == 0).any():
            return None  # two points in a cell
        scale[dot_cells] = _POW10[upto[dot_cells] - seen[dots]]
    values = mant / scale
    if minus.size:
        values[cell_of[minus]] *= -1.0
    for i in np.flatnonzero(special).tolist():
        try:
            values[i] = float(raw[starts[i]:ends[i]])
        except ValueError:
            return None
    return values


def _read_plain_table(src: _Source) -> tuple[list[str], np.ndarray, np.ndarray] | None:
    """Fast path for the common case (no quotes, no blank lines, every cell a finite number,
    time in seconds): numpy's C parser, ~10x faster on day-long 1 s runs. None means "use the
    careful reader", which also produces the exact error message for anything irregular."""
    text = src.text
    if '"' in text or src.time_col is not None:
        return None
    nl = text.find("\n")
    head = text[:nl]
    if src.decimal == "." and nl > 0 and head.splitlines() == [head]:
        # the rows straight from the text, no list of lines (200 MB at 346k rows): a file
        # the vectorised reader takes has no other line break, no blank line, and every row
        # the header's length, so its rows are the lines the path below would split
        header = [h.strip() for h in head.split(src.sep)]
        if not _plain_header(header):
            return None
        data = _plain_numbers(text, nl + 1, src.sep, len(header))
        if data is not None:
            return _plain_result(src, header, data)
    lines = text.splitlines()
    if len(lines) < 2:
        return None
    header = [h.strip() for h in lines[0].split(src.sep)]
    body = lines[1:]
    if not _plain_header(header) or any(not line.strip() for line in body):
        return None
    data = None
    if src.decimal == ",":
        if any("." in line and "," in line for line in body):
            return None  # a thousands separator or a mix: the careful reader says where
        body = [line.replace(",", ".") for line in body]
        data = _plain_numbers("\n".join(body), 0, src.sep, len(header), len(body))
    if data is None:
        try:
            data = np.loadtxt(body, delimiter=src.sep, comments=None, ndmin=2, dtype=float)
        except ValueError:
            return None
    if data.shape != (len(body), len(header)):
        return None
    return _plain_result(src, header, data)


def _plain_header(header: list[str]) -> bool:
    """Column names the fast path takes: none empty, none twice, a time column."""
    return (all(header) and len(set(header)) == len(header) and TIME_COLUMN in header)


def _plain_result(src: _Source, header: list[str], data: np.ndarray
                  ) -> tuple[list[str], np.ndarray, np.ndarray] | None:
    """The fast path's table (time in seconds, the file lines 2, 3, ...), None if a cell is
    infinite (the careful reader says where)."""
    if np.isinf(data).any():
        return None
    if src.time_unit is not None:
        data[:, header.index(TIME_COLUMN)] *= TIME_UNITS[src.time_unit]
    return header, data, np.arange(2, 2 + data.shape[0])


def _number(src: _Source, text: str, line: int, column: str) -> float:
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


def _numbers(src: _Source, cells: list[str], lines: list[int], column: str) -> np.ndarray:
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


# A date written day.month.year (dd.mm.yyyy, as German and many European loggers write it),
# or with '/' or '-' (dd/mm/yyyy or mm/dd/yyyy: which one the column's dates must tell), with
# an optional time of day.
_DATE = re.compile(r"^(\d{1,2})([./-])(\d{1,2})\2(\d{4})"
                   r"(?:[ T](\d{1,2}):(\d{2})(?::(\d{2})(?:[.,](\d{1,6}))?)?)?$")


def _date_order(src: _Source, cells: list[str], lines: list[int], column: str) -> str:
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


def _timestamps(src: _Source, cells: list[str], lines: list[int], column: str) -> np.ndarray:
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


def _is_timestamp(text: str) -> bool:
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


def _time_column(src: _Source, header: list[str], first_row: list[str] | None) -> int | None:
    """Index of the time column (which becomes time_s), or None."""
    if src.time_col is not None:
        if src.time_col not in header:
            raise RunFormatError(src.path, "missing time column (given by --time-col)", line=1,
                                 column=src.time_col)
        if src.time_col != TIME_COLUMN and TIME_COLUMN in header:
            raise RunFormatError(src.path, f"--time-col '{src.time_col}' given, but the file "
                                 f"also has a column '{TIME_COLUMN}'", line=1,
                                 column=TIME_COLUMN)
        return header.index(src.time_col)
    if TIME_COLUMN in header:
        return header.index(TIME_COLUMN)
    if first_row is not None:  # numbers in a column named 'time' could be minutes: not guessed
        stamps = [i for i, c in enumerate(first_row[:len(header)]) if _is_timestamp(c.strip())]
        if len(stamps) == 1:
            return stamps[0]
    return None


def read_header(path: str | Path, fmt: CsvFormat | None = None) -> list[str]:
    """The column names of a run file as ``read_table`` names them (time column: time_s),
    from its first two rows."""
    path = Path(path)
    if not path.is_file():
        raise RunFormatError(path, "file not found")
    src = _source(path, fmt)
    reader = csv.reader(io.StringIO(src.text, newline=""), delimiter=src.sep)
    header = [h.strip() for h in next(reader, [])]
    if not header:
        raise RunFormatError(path, "empty file (no header row)", line=1)
    first = next(reader, None)
    time_idx = _time_column(src, header, [c.strip() for c in first] if first else None)
    if time_idx is not None:
        header[time_idx] = TIME_COLUMN
    return header


def read_table(path: str | Path, fmt: CsvFormat | None = None
               ) -> tuple[list[str], np.ndarray, np.ndarray]:
    """Read a CSV with a header into names, a float array and each row's file line number.

    NaN marks empty/'nan' cells. ``fmt`` (default: everything sniffed, see CsvFormat) gives
    the delimiter, the decimal mark and the time column; the time column is returned as
    ``time_s`` in seconds.

    Rejects non-UTF-8 files, duplicate or empty header names, ragged rows and non-numeric
    cells, naming file, line (1-based, header is line 1) and column.
    """
    path = Path(path)
    if not path.is_file():
        raise RunFormatError(path, "file not found")
    src = _source(path, fmt)
    fast = _read_plain_table(src)
    if fast is not None:
        return fast
    reader = csv.reader(io.StringIO(src.text, newline=""), delimiter=src.sep)
    try:
        header = next(reader)
    except StopIteration:
        raise RunFormatError(path, "empty file (no header row)", line=1) from None
    header = [h.strip() for h in header]
    seen: dict[str, int] = {}
    for i, name in enumerate(header):
        if not name:
            raise RunFormatError(path, f"empty column name at position {i + 1}", line=1)
        if name in seen:
            raise RunFormatError(path, f"duplicate column (also at position {seen[name] + 1})",
                                 line=1, column=name)
        seen[name] = i
    rows: list[list[str]] = []
    lines: list[int] = []
    for row in reader:
        if not row or all(not c.strip() for c in row):
            continue
        if len(row) != len(header):
            raise RunFormatError(path, f"{len(row)} cells, header has {len(header)}",
                                 line=reader.line_num)
        rows.append([c.strip() for c in row])
        lines.append(reader.line_num)
    time_idx = _time_column(src, header, rows[0] if rows else None)
    data = np.empty((len(rows), len(header)))
    for j, name in enumerate(header):
        cells = [r[j] for r in rows]
        if j == time_idx and cells and any(_is_timestamp(c) for c in cells[:1]):
            data[:, j] = _timestamps(src, cells, lines, name)
        else:
            data[:, j] = _numbers(src, cells, lines, name)
            if j == time_idx and src.time_unit is not None:  # numbers in that unit
                data[:, j] *= TIME_UNITS[src.time_unit]
    if time_idx is not None:
        header[time_idx] = TIME_COLUMN
    return header, data, np.array(lines, dtype=int)


def _fill_gaps(path: Path, name: str, values: np.ndarray, time_s: np.ndarray,
               max_gap: int, lines: np.ndarray) -> int:
    """Linearly interpolate interior NaN runs no longer than max_gap samples, in place."""
    nan = np.isnan(values)
    if not nan.any():
        return 0
    idx = np.flatnonzero(nan)
    # split into contiguous runs
    breaks = np.flatnonzero(np.diff(idx) > 1)
    starts = np.concatenate(([idx[0]], idx[breaks + 1]))
    ends = np.concatenate((idx[breaks], [idx[-1]]))
    filled = 0
    for s, e in zip(starts, ends, strict=True):
        length = e - s + 1
        if s == 0 or e == len(values) - 1:
            raise RunFormatError(path, "missing value at the start or end of the run cannot be "
                                 "interpolated", line=int(lines[s]), column=name)
        if length > max_gap:
            raise RunFormatError(path, f"gap of {length} missing samples is longer than "
                                 f"--fill-gaps {max_gap}", line=int(lines[s]), column=name)
        values[s:e + 1] = np.interp(time_s[s:e + 1], [time_s[s - 1], time_s[e + 1]],
                                    [values[s - 1], values[e + 1]])
        filled += int(length)
    return filled


# Time and value checks. A run's steps must be one period (the median step) within
# JITTER_TOLERANCE; a step beyond GAP_FACTOR periods is a gap (missing rows).
JITTER_TOLERANCE = 0.05
GAP_FACTOR = 1.5
MS_MIN_PERIOD = 100.0  # "seconds": time_s in ms has steps of 100..60000 for 0.1 s..1 min
MS_MIN_SPAN_S = 14 * 86400.0  # ... and spans months; a thermal test lasts hours to days.
# A step of a whole number of thousands (1000, 2000, 60000) is taken as whole seconds in ms
# too: a thermal test does not sample every 16.7 minutes on the dot.
# A time_s span beyond a year even when read as milliseconds is no thermal test in any unit
# (a 1e300 is a logger's error code, not milliseconds): refused as out of range.
MAX_SPAN_AS_MS = 366 * 86400.0 * 1000
TARGET_LIMIT_UM = INT32_MAX / 1000  # the box's correction is int32 nanometres
AUX_LIMIT = float(INT32_MAX)  # the box's aux inputs are int32
DEFAULT_TEMPERATURE_RANGE = (CHANNEL_MIN_C, CHANNEL_MAX_C)


def _check_time(path: Path, time_s: np.ndarray, lines: np.ndarray, fill_gaps: int,
                guess: bool = True) -> list[tuple[int, int]]:
    """Refuse time in ms (unless its unit was given: ``guess`` False), gaps and jitter; return
    the gaps (row index, missing rows) that ``fill_gaps`` allows to fill."""
    steps = np.diff(time_s)
    if steps.size == 0:
        return []
    far = np.flatnonzero(np.abs(time_s - time_s[0]) > MAX_SPAN_AS_MS)
    if far.size:
        i = int(far[0])
        raise RunFormatError(
            path, f"time_s {time_s[i]:g} is out of range: {time_s[i] - time_s[0]:.3g} after "
            f"the first sample ({time_s[0]:g}), more than a year even if these were "
            "milliseconds (a thermal test run lasts hours to days; a logger's error code?)",
            line=int(lines[i]), column=TIME_COLUMN)
    period = float(np.median(steps))
    span = float(time_s[-1] - time_s[0])
    whole_seconds_in_ms = period >= 1000 and abs(period / 1000 - round(period / 1000)) < 1e-9
    if guess and ((period >= MS_MIN_PERIOD and span >= MS_MIN_SPAN_S) or whole_seconds_in_ms):
        raise RunFormatError(
            path, f"time_s looks like milliseconds: steps of {period:g} and a span of "
            f"{span / 86400:.3g} days if these were seconds (a thermal test run lasts hours to "
            f"days); pass --time-unit ms to read it as milliseconds, or write time_s in seconds, "
            f"i.e. divide by 1000 (a step of {period / 1000:g} s, {span / 3600000:.3g} h); if "
            "these really are seconds, pass --time-unit s", column=TIME_COLUMN)
    ratio = steps / period
    gaps = np.flatnonzero(ratio > GAP_FACTOR)
    fill: list[tuple[int, int]] = []
    for g in gaps:
        k = round(float(ratio[g]))
        if 0 < k - 1 <= fill_gaps and abs(ratio[g] - k) <= JITTER_TOLERANCE:
            fill.append((int(g) + 1, k - 1))
            continue
        i = int(g) + 1
        missing = float(ratio[g]) - 1
        more = len(gaps) - len(fill) - 1
        hint = (f", or interpolate the {k - 1} missing rows with --fill-gaps {k - 1}"
                if k - 1 <= 10 and abs(ratio[g] - k) <= JITTER_TOLERANCE else "")
        raise RunFormatError(
            path, f"time_s jumps from {time_s[i - 1]:g} to {time_s[i]:g} s: a gap of "
            f"{steps[g]:g} s, about {missing:.4g} missing samples of the {period:g} s period"
            f"{f' ({more} more gaps after it)' if more > 0 else ''}. The model's filters and "
            "the box assume one sample every period, so a gap means they restart: cut the run "
            f"there (host split {path} --at-hours {time_s[i] / 3600:.6g}) and use the parts as "
            f"separate runs{hint}", line=int(lines[i]), column=TIME_COLUMN)
    # No gap left (or only gaps to fill): the period the timestamps imply is the slope of a
    # straight line through them (the median step is not: +-7 s jitter made it 67 s of 60).
    k = np.arange(len(time_s), dtype=float)
    if fill:
        k += np.repeat(np.cumsum([0, *(n for _, n in fill)]),
                       np.diff([0, *(i for i, _ in fill), len(time_s)]))
    grid = float(np.polyfit(k, time_s, 1)[0]) if len(time_s) > 2 else period
    step_k = np.diff(k)
    off = np.flatnonzero(np.abs(steps / step_k / grid - 1) > JITTER_TOLERANCE)
    if off.size:
        i = int(off[0]) + 1
        resid = time_s - grid * k
        jitter = (resid.max() - resid.min()) / 2
        plain = steps[step_k == 1] if (step_k == 1).any() else steps
        lo, hi = float(plain.min()), float(plain.max())
        raise RunFormatError(
            path, f"time_s is irregular: the samples deviate up to ±{jitter:.2g} s from a "
            f"regular grid of {grid:.4g} s, the period they imply (steps from {lo:g} to {hi:g} "
            f"s; {off.size} of {steps.size} steps off by more than {100 * JITTER_TOLERANCE:g} "
            f"%, the first here: {time_s[i - 1]:g} to {time_s[i]:g} s). The model's filters and "
            f"the box assume one fixed period: resample the run to {grid:.4g} s",
            line=int(lines[i]), column=TIME_COLUMN)
    return fill


def _insert_rows(time_s: np.ndarray, data: np.ndarray, lines: np.ndarray,
                 fill: list[tuple[int, int]], time_col: int
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Insert ``n`` NaN rows on a regular time grid before each row index of ``fill``."""
    blocks, line_blocks, last = [], [], 0
    for i, n in fill:
        blocks.append(data[last:i])
        line_blocks.append(lines[last:i])
        rows = np.full((n, data.shape[1]), np.nan)
        rows[:, time_col] = np.linspace(time_s[i - 1], time_s[i], n + 2)[1:-1]
        blocks.append(rows)
        line_blocks.append(np.full(n, lines[i]))
        last = i
    blocks.append(data[last:])
    line_blocks.append(lines[last:])
    return np.vstack(blocks), np.concatenate(line_blocks)


def _check_values(path: Path, name: str, values: np.ndarray, lines: np.ndarray, lo: float,
                  hi: float, what: str) -> None:
    bad = np.flatnonzero((values < lo) | (values > hi))
    if not bad.size:
        return
    i = int(bad[0])
    raise RunFormatError(path, f"{values[i]:g} {what}", line=int(lines[i]), column=name)


def _check_temperatures(path: Path, name: str, values: np.ndarray, lines: np.ndarray,
                        lo: float, hi: float) -> None:
    bad = np.flatnonzero((values < lo) | (values > hi))
    if not bad.size:
        return
    i = int(bad[0])
    finite = values[~np.isnan(values)]
    hint = ""
    if finite.min() >= lo + 273.15 and finite.max() <= hi + 273.15:
        hint = (f"; the whole column ({finite.min():g}..{finite.max():g}) looks like kelvin: "
                "pass --temp-unit K to read it as kelvin, or give degC (subtract 273.15)")
    elif finite.min() >= lo * 1.8 + 32 and finite.max() <= hi * 1.8 + 32 and finite.max() > hi:
        hint = (f"; the whole column ({finite.min():g}..{finite.max():g}) could be degF "
                f"({(finite.min() - 32) / 1.8:.3g}..{(finite.max() - 32) / 1.8:.3g} degC): pass "
                "--temp-unit F to read it as degF")
    raise RunFormatError(
        path, f"{values[i]:g} degC is outside the thermocouple channel's valid range "
        f"{lo:g}..{hi:g} degC ({bad.size} such cell{'s' if bad.size > 1 else ''}): the box "
        "would read it as a fault; a sensor fault, a logger's error code or a wrong unit, not a "
        f"temperature{hint}",
        line=int(lines[i]), column=name)


def did_you_mean(name: str, candidates: Sequence[str]) -> str:
    """" (did you mean 'T12'?)" for the closest of ``candidates`` (difflib), else ""."""
    close = difflib.get_close_matches(name, list(candidates), n=1, cutoff=0.6)
    if not close:
        close = [c for c in candidates if c.lower() == name.lower()][:1]
    return f" (did you mean '{close[0]}'?)" if close else ""


def missing_sensors(missing: Sequence[str], available: Sequence[str], why: str) -> str:
    """The one phrasing of "the run lacks sensor columns", wherever it is found:
    "missing sensor column(s) T13 (did you mean 'T12'?), T07x (did you mean 'T07'?): the
    model reads them; the run's sensor columns: T01, ..., T12"."""
    named = ", ".join(f"{m}{did_you_mean(m, available)}" for m in missing)
    shown = ", ".join(available[:16]) + (", ..." if len(available) > 16 else "")
    return (f"missing sensor column(s) {named}: {why}; the run's columns: {shown or 'none'}")


# What a thermal test run in the project's units looks like, and so what another unit looks like
# (each guess is skipped when the unit is given: CsvFormat, --time-unit/--temp-unit/--disp-unit).
MINUTES_MAX_SPAN_S = 2 * 3600.0  # "seconds": a run this short ...
MINUTES_MIN_WARMING_C = 5.0  # ... in which a sensor changes this much: a machine tool does not
MINUTES_MIN_SAMPLES = 240  # warm 5 degC in minutes of a thermal test; in minutes it is hours
# (240 samples: 4 h of one a minute; a shorter run at a step of 1 is not told from a hand-made
# one in seconds. A step below 1 that is whole seconds as minutes, 0.5 or 0.25, needs 120.)
MINUTES_MAX_STEP_SHARE = 0.02  # ... and a smooth warming, as a machine's: the median change
# from one sample to the next is under 2 % of the whole change (noise is not a warming)
FAHRENHEIT_MIN = 45.0  # every sensor of the run at or above this for the whole run (7 degC in
# degF; as degC the coolest point of the machine, the bed or the air, would be at 45 degC)
MM_MAX_DRIFT = 0.25  # every displacement moving less than this while a sensor warms ...
MM_MIN_WARMING_C = 1.0  # ... this much: micrometres do not stay this still (steel: 1.2 um/K/100 mm)
NM_MIN_DRIFT = 1000.0  # a displacement moving more than this: 1 mm of thermal drift in a test


def _sniff_units(path: Path, time_s: np.ndarray, temps: Mapping[str, np.ndarray],
                 disps: Mapping[str, np.ndarray], fmt: CsvFormat | None) -> None:
    """Refuse a run that looks written in another unit than seconds, degC and micrometres
    (minutes, degF, mm, nm), saying what it looks like and what to pass. Kelvin and
    milliseconds are out of range and refused where the range is checked."""
    fmt = fmt or CsvFormat()
    warming = {n: float(np.nanmax(v) - np.nanmin(v)) for n, v in temps.items()
               if np.isfinite(v).any()}
    hottest = max(warming, key=lambda n: warming[n]) if warming else None
    span = float(time_s[-1] - time_s[0]) if time_s.size else 0.0
    period = float(np.median(np.diff(time_s))) if time_s.size > 1 else 0.0
    whole_s = 0 < period < 1 and abs(period * 60 - round(period * 60)) < 1e-6
    enough = time_s.size >= (MINUTES_MIN_SAMPLES // 2 if whole_s else MINUTES_MIN_SAMPLES)
    if fmt.time_unit is None and hottest is not None and enough and 0 < period <= 1.0 \
            and 0 < span <= MINUTES_MAX_SPAN_S and warming[hottest] >= MINUTES_MIN_WARMING_C:
        steps = np.abs(np.diff(temps[hottest]))
        if float(np.nanmedian(steps)) <= MINUTES_MAX_STEP_SHARE * warming[hottest]:
            raise RunFormatError(
                path, f"time_s looks like minutes: steps of {period:g} and a span of {span:g}, "
                f"{span / 60:.3g} min if these were seconds, while {hottest} changes by "
                f"{warming[hottest]:.3g} degC (a machine tool does not warm that fast; the "
                "lags' time constants would come out 60x too short); as minutes it is a step of "
                f"{period * 60:g} s and a run of {span / 60:.3g} h: pass --time-unit min to read "
                "it as minutes (or write time_s in seconds); if these really are seconds, pass "
                "--time-unit s", column=TIME_COLUMN)
    if fmt.temp_unit is None and len(temps) >= 2:
        lows = {n: float(np.nanmin(v)) for n, v in temps.items() if np.isfinite(v).any()}
        if lows and min(lows.values()) >= FAHRENHEIT_MIN:
            lo = min(lows.values())
            hi = max(float(np.nanmax(v)) for v in temps.values() if np.isfinite(v).any())
            coolest = min(lows, key=lambda n: lows[n])
            raise RunFormatError(
                path, f"the temperatures look like degF: every sensor reads {lo:g} or more for "
                f"the whole run ({lo:g}..{hi:g}; the coolest, {coolest}, never below {lo:g}), "
                f"as degC no part of the machine nor the air would be below {lo:g} degC; as "
                f"degF they are {(lo - 32) / 1.8:.3g}..{(hi - 32) / 1.8:.3g} degC: pass "
                "--temp-unit F to read them as degF; if they really are degC, pass "
                "--temp-unit C", column=coolest)
    if fmt.disp_unit is None and disps:
        drift = {n: float(np.nanmax(v) - np.nanmin(v)) for n, v in disps.items()
                 if np.isfinite(v).any()}
        if not drift:
            return
        widest = max(drift, key=lambda n: drift[n])
        if drift[widest] > NM_MIN_DRIFT:
            raise RunFormatError(
                path, f"the displacements look like nanometres: {widest} moves by "
                f"{drift[widest]:.6g} over the run, {drift[widest] / 1000:.3g} mm if these were "
                "micrometres (a thermal drift is microns to a few hundred microns); as "
                f"nanometres it is {drift[widest] / 1000:.4g} um: pass --disp-unit nm to read "
                "them as nanometres; if they really are micrometres, pass --disp-unit um",
                column=widest)
        if hottest is not None and warming[hottest] >= MM_MIN_WARMING_C \
                and 0 < drift[widest] < MM_MAX_DRIFT:
            raise RunFormatError(
                path, f"the displacements look like millimetres: the most any moves is "
                f"{drift[widest]:.4g} ({widest}) while {hottest} warms by "
                f"{warming[hottest]:.3g} degC; as micrometres the machine would not have moved "
                f"(nothing to compensate), as millimetres it is {drift[widest] * 1000:.4g} um: "
                "pass --disp-unit mm to read them as millimetres; if they really are "
                "micrometres, pass --disp-unit um", column=widest)


def load_run(path: str | Path, targets: list[str], sensors: str | list[str] = "T*",
             aux: list[str] | None = None, fill_gaps: int = 0, min_samples: int = 2,
             fmt: CsvFormat | None = None,
             temperature_ranges: Mapping[str, tuple[float, float]] | None = None,
             tilts: Sequence[Tilt] = (), targets_from: str = "given by --target",
             sensors_from: str = "given by --sensors", aux_from: str = "given by --aux"
             ) -> Run:
    """Load one run.

    ``sensors`` is a glob (``"T*"``) or an explicit list of column names. ``fill_gaps`` > 0
    interpolates interior gaps of at most that many samples, empty cells and missing rows
    alike (reported in ``filled_cells``); 0 rejects every empty cell and every gap.
    ``min_samples`` is the least the caller's model needs. ``fmt``: delimiter, decimal mark
    and time column (default: sniffed, see CsvFormat). Temperatures must lie in their
    channel's valid range (``temperature_ranges`` by sensor, default the box's
    CHANNEL_MIN_C..CHANNEL_MAX_C), displacements within the box's int32 nanometres, aux values
    within int32; time_s must be seconds at one fixed period (no gap, no jitter).
    A target named by one of ``tilts`` is computed from its two gap-probe columns (µrad,
    contract/tilt.py); the probes are checked like any displacement column.
    ``targets_from``, ``sensors_from``, ``aux_from``: where the caller's column names come
    from, for the refusal of a missing column (a model's axes are no ``--target``).
    """
    path = Path(path)
    aux = list(aux or [])
    tilt_of = {t.name: t for t in tilts if t.name in targets}
    requested, targets = list(targets), probe_columns(targets, list(tilt_of.values()))
    header, data, lines = read_table(path, fmt)
    if TIME_COLUMN not in header:
        hint = (f"; the header is one column ({header[0][:60]!r}): is the file delimited by "
                "another character? pass --sep" if len(header) == 1 else
                "; name the time column with --time-col")
        raise RunFormatError(path, f"missing column '{TIME_COLUMN}'{hint}", line=1,
                             column=TIME_COLUMN)
    for name in targets:
        if name not in header:
            tilt = next((t for t in tilt_of.values() if name in (t.upper, t.lower)), None)
            given = (f"a gap probe of --tilt {tilt.name}" if tilt is not None
                     else targets_from)
            raise RunFormatError(path, f"missing target column ({given})"
                                 f"{did_you_mean(name, header)}", line=1, column=name)
    for name in aux:
        if name not in header:
            raise RunFormatError(path, f"missing auxiliary column ({aux_from})"
                                 f"{did_you_mean(name, header)}", line=1, column=name)
    reserved = {TIME_COLUMN, *targets, *aux}
    if isinstance(sensors, str):
        sensor_names = [h for h in header if fnmatch.fnmatchcase(h, sensors) and h not in reserved]
        if not sensor_names:
            raise RunFormatError(path, f"no temperature column matches --sensors '{sensors}'",
                                 line=1)
    else:
        sensor_names = list(sensors)
        missing = [n for n in sensor_names if n not in header]
        if missing:
            raise RunFormatError(path, missing_sensors(
                missing, [h for h in header if h not in reserved], sensors_from), line=1)
    if data.shape[0] < min_samples:
        raise RunFormatError(path, f"{data.shape[0]} samples, the model needs at least "
                             f"{min_samples}")

    col = {name: header.index(name) for name in header}
    time_s = data[:, col[TIME_COLUMN]].copy()
    bad = np.flatnonzero(np.isnan(time_s))
    if bad.size:
        raise RunFormatError(path, "empty time", line=int(lines[bad[0]]),
                             column=TIME_COLUMN)
    steps = np.diff(time_s)
    bad = np.flatnonzero(steps <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        raise RunFormatError(path, f"time does not increase ({time_s[i - 1]:g} then "
                             f"{time_s[i]:g})", line=int(lines[i]), column=TIME_COLUMN)
    fill = _check_time(path, time_s, lines, fill_gaps,
                       guess=fmt is None or fmt.time_unit is None)
    if fill:
        data, lines = _insert_rows(time_s, data, lines, fill, col[TIME_COLUMN])
        time_s = data[:, col[TIME_COLUMN]].copy()

    if fmt is not None:  # the units given: to degC and micrometres before anything is checked
        for name in sensor_names:
            data[:, col[name]] = to_celsius(data[:, col[name]], fmt.temp_unit)
        for name in targets:
            data[:, col[name]] *= DISP_UNITS[fmt.disp_unit or "um"]
    ranges = temperature_ranges or {}
    for name in sensor_names:
        lo, hi = ranges.get(name, DEFAULT_TEMPERATURE_RANGE)
        _check_temperatures(path, name, data[:, col[name]], lines, lo, hi)
    for name in targets:
        _check_values(path, name, data[:, col[name]], lines, -TARGET_LIMIT_UM, TARGET_LIMIT_UM,
                      f"um is beyond any correction the box can output (±{TARGET_LIMIT_UM:g} "
                      "um, int32 nanometres): a displacement column must be in micrometres")
    for name in aux:
        _check_values(path, name, data[:, col[name]], lines, -AUX_LIMIT, AUX_LIMIT,
                      f"is beyond the box's int32 auxiliary input (±{AUX_LIMIT:g})")
    _sniff_units(path, time_s, {n: data[:, col[n]] for n in sensor_names},
                 {n: data[:, col[n]] for n in targets}, fmt)

    filled = 0
    used = [*sensor_names, *targets, *aux]
    arrays: dict[str, np.ndarray] = {}
    for name in used:
        values = data[:, col[name]].copy()
        if np.isnan(values).any():
            if fill_gaps <= 0:
                i = int(np.flatnonzero(np.isnan(values))[0])
                raise RunFormatError(path, "empty or NaN cell (use --fill-gaps N to interpolate "
                                     "short gaps)", line=int(lines[i]), column=name)
            filled += _fill_gaps(path, name, values, time_s, fill_gaps, lines)
        arrays[name] = values

    def stack(names: list[str]) -> np.ndarray:
        if not names:
            return np.empty((len(time_s), 0))
        return np.column_stack([arrays[n] for n in names])

    for name, tilt in tilt_of.items():
        arrays[name] = tilt.of(arrays[tilt.upper], arrays[tilt.lower])
        _check_values(path, name, arrays[name], lines, -TARGET_LIMIT_UM, TARGET_LIMIT_UM,
                      f"urad is beyond any correction the box can output (±{TARGET_LIMIT_UM:g}"
                      f" urad): are the probes {tilt.distance_mm:g} mm apart, in micrometres?")
    return Run(str(path), time_s, sensor_names, stack(sensor_names), requested,
               stack(requested), aux, stack(aux) if aux else None, filled)


def load_runs(paths: list[str | Path], targets: list[str], sensors: str | list[str] = "T*",
              aux: list[str] | None = None, fill_gaps: int = 0, min_samples: int = 2,
              fmt: CsvFormat | None = None, tilts: Sequence[Tilt] = ()) -> list[Run]:
    """Load several runs; all must have the same sensor columns in the same order."""
    runs = [load_run(p, targets, sensors, aux, fill_gaps, min_samples, fmt, tilts=tilts)
            for p in paths]
    for run in runs[1:]:
        if run.sensor_names != runs[0].sensor_names:
            missing = sorted(set(runs[0].sensor_names) ^ set(run.sensor_names))
            raise RunFormatError(run.path, f"sensor columns differ from {runs[0].path}: "
                                 f"{', '.join(missing) or 'order differs'}", line=1)
    return runs


def check_variation(runs: list[Run], targets: list[str]) -> None:
    """Refuse training runs with nothing to learn: a target constant in every run, or every
    sensor constant in every run."""
    names = ", ".join(r.path for r in runs)
    for t in targets:
        values = [r.target(t) for r in runs]
        if all(np.ptp(v) == 0 for v in values):
            level = ", ".join(f"{v[0]:g}" for v in values[:3])
            raise RunFormatError(runs[0].path, f"target '{t}' is constant in every training run "
                                 f"({names}: {level} um): there is no thermal drift to model; "
                                 "is it the right column, was the probe connected?", column=t)
    if runs and all(np.ptp(r.temperatures, axis=0).max(initial=0) == 0 for r in runs):
        raise RunFormatError(runs[0].path, f"every sensor ({', '.join(runs[0].sensor_names)}) is "
                             f"constant in every training run ({names}): there is no temperature "
                             "change to learn from; were the thermocouples read?")


def write_run(path: str | Path, time_s: np.ndarray, columns: dict[str, np.ndarray],
              precision: int = 6) -> None:
    """Write a run in the project's CSV format (atomic: temp file then rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    names = [TIME_COLUMN, *columns]
    table = np.column_stack([time_s, *columns.values()])
    with tmp.open("w", newline="") as fh:
        fh.write(",".join(names) + "\n")
        fmt = f"%.{precision}g"
        np.savetxt(fh, table, delimiter=",", fmt=fmt)
    tmp.replace(path)

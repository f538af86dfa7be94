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
import fnmatch
import io
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

import numpy as np

from contract.box import CHANNEL_MAX_C, CHANNEL_MIN_C
from contract.errors import InputError, MissingColumnError
from contract.fixed_point import INT32_MAX
from contract.textfile import read_utf8
from contract.tilt import Tilt, probe_columns

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
    """

    sep: str | None = None
    decimal: str | None = None
    time_col: str | None = None

    def __post_init__(self) -> None:
        sep, decimal = self.sep, self.decimal
        if sep is not None and (len(sep) != 1 or sep in "\"\r\n" or sep.isalnum()):
            raise InputError(f"--sep must be one character such as ',' ';' or a tab, got {sep!r}")
        if decimal not in (None, ".", ","):
            raise InputError(f"--decimal must be '.' or ',', got {decimal!r}")
        if decimal == "," and sep == ",":
            raise InputError("--decimal ',' needs a --sep other than ',' (e.g. --sep ';')")


@dataclass(frozen=True)
class _Source:
    """A decoded run file and the format it is read with."""

    path: Path
    text: str
    sep: str
    decimal: str
    time_col: str | None  # as given (--time-col); None: time_s or sniffed


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
    return _Source(path, text, sep, decimal, fmt.time_col)


def _read_plain_table(src: _Source) -> tuple[list[str], np.ndarray, np.ndarray] | None:
    """Fast path for the common case (no quotes, no blank lines, every cell a finite number,
    time in seconds): numpy's C parser, ~10x faster on day-long 1 s runs. None means "use the
    careful reader", which also produces the exact error message for anything irregular."""
    text = src.text
    if '"' in text or src.time_col is not None:
        return None
    lines = text.splitlines()
    if len(lines) < 2:
        return None
    header = [h.strip() for h in lines[0].split(src.sep)]
    body = lines[1:]
    if (any(not h for h in header) or len(set(header)) != len(header)
            or TIME_COLUMN not in header or any(not line.strip() for line in body)):
        return None
    if src.decimal == ",":
        if any("." in line and "," in line for line in body):
            return None  # a thousands separator or a mix: the careful reader says where
        body = [line.replace(",", ".") for line in body]
    try:
        data = np.loadtxt(body, delimiter=src.sep, comments=None, ndmin=2, dtype=float)
    except ValueError:
        return None
    if data.shape != (len(body), len(header)) or np.isinf(data).any():
        return None
    return header, data, np.arange(2, 2 + len(body))


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
        if "," in text and src.decimal == ".":
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


def _timestamps(src: _Source, cells: list[str], lines: list[int], column: str) -> np.ndarray:
    """ISO 8601 timestamps -> seconds since the first one (empty cells NaN)."""
    out = np.full(len(cells), math.nan)
    t0: datetime | None = None
    for i, (text, line) in enumerate(zip(cells, lines, strict=True)):
        if not text:
            continue
        try:
            stamp = datetime.fromisoformat(text)
        except ValueError:
            raise RunFormatError(src.path, f"not a number of seconds nor an ISO 8601 timestamp: "
                                 f"{text!r} (e.g. 2024-03-01T12:00:00 or 2024-03-01 12:00:00,5)",
                                 line=line, column=column) from None
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
        return False


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


def _check_time(path: Path, time_s: np.ndarray, lines: np.ndarray, fill_gaps: int
                ) -> list[tuple[int, int]]:
    """Refuse time in ms, gaps and jitter; return the gaps (row index, missing rows) that
    ``fill_gaps`` allows to fill."""
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
    if (period >= MS_MIN_PERIOD and span >= MS_MIN_SPAN_S) or whole_seconds_in_ms:
        raise RunFormatError(
            path, f"time_s looks like milliseconds: steps of {period:g} and a span of "
            f"{span / 86400:.3g} days if these were seconds (a thermal test run lasts hours to "
            f"days); write time_s in seconds, i.e. divide by 1000 (a step of {period / 1000:g} s, "
            f"{span / 3600000:.3g} h)", column=TIME_COLUMN)
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
                "give degC (subtract 273.15)")
    raise RunFormatError(
        path, f"{values[i]:g} degC is outside the thermocouple channel's valid range "
        f"{lo:g}..{hi:g} degC ({bad.size} such cell{'s' if bad.size > 1 else ''}): the box "
        "would read it as a fault; a sensor fault, a logger's error code or a wrong unit, not a "
        f"temperature{hint}",
        line=int(lines[i]), column=name)


def load_run(path: str | Path, targets: list[str], sensors: str | list[str] = "T*",
             aux: list[str] | None = None, fill_gaps: int = 0, min_samples: int = 2,
             fmt: CsvFormat | None = None,
             temperature_ranges: Mapping[str, tuple[float, float]] | None = None,
             tilts: Sequence[Tilt] = ()) -> Run:
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
                     else "given by --target")
            raise RunFormatError(path, f"missing target column ({given})", line=1,
                                 column=name)
    for name in aux:
        if name not in header:
            raise RunFormatError(path, "missing auxiliary column (given by --aux)", line=1,
                                 column=name)
    reserved = {TIME_COLUMN, *targets, *aux}
    if isinstance(sensors, str):
        sensor_names = [h for h in header if fnmatch.fnmatchcase(h, sensors) and h not in reserved]
        if not sensor_names:
            raise RunFormatError(path, f"no temperature column matches --sensors '{sensors}'",
                                 line=1)
    else:
        sensor_names = list(sensors)
        for name in sensor_names:
            if name not in header:
                raise RunFormatError(path, "missing sensor column", line=1, column=name)
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
    fill = _check_time(path, time_s, lines, fill_gaps)
    if fill:
        data, lines = _insert_rows(time_s, data, lines, fill, col[TIME_COLUMN])
        time_s = data[:, col[TIME_COLUMN]].copy()

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

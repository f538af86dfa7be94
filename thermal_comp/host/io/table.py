"""Read a run file into column names, numbers and each row's file line: the careful reader
names file, line and column of anything it refuses (ragged rows, duplicate names, bad cells),
and the lines let every later check name its cell too."""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from thermal_comp.host.io.cells import column_numbers, column_timestamps, is_timestamp
from thermal_comp.host.io.csv_format import TIME_UNITS, CsvFormat, Source, read_source
from thermal_comp.host.io.fast_table import read_plain_table
from thermal_comp.host.io.format_error import RunFormatError
from thermal_comp.host.io.run import TIME_COLUMN


def _time_column(src: Source, header: list[str], first_row: list[str] | None) -> int | None:
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
        stamps = [i for i, c in enumerate(first_row[:len(header)]) if is_timestamp(c.strip())]
        if len(stamps) == 1:
            return stamps[0]
    return None


def read_header(path: str | Path, fmt: CsvFormat | None = None) -> list[str]:
    """The column names of a run file as ``read_table`` names them (time column: time_s),
    from its first two rows."""
    path = Path(path)
    if not path.is_file():
        raise RunFormatError(path, "file not found")
    src = read_source(path, fmt)
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
    src = read_source(path, fmt)
    fast = read_plain_table(src)
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
        if j == time_idx and cells and any(is_timestamp(c) for c in cells[:1]):
            data[:, j] = column_timestamps(src, cells, lines, name)
        else:
            data[:, j] = column_numbers(src, cells, lines, name)
            if j == time_idx and src.time_unit is not None:  # numbers in that unit
                data[:, j] *= TIME_UNITS[src.time_unit]
    if time_idx is not None:
        header[time_idx] = TIME_COLUMN
    return header, data, np.array(lines, dtype=int)

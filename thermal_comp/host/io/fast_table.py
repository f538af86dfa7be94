"""The fast path for the common run file (no quotes, no blank lines, every cell a finite
number): ~10x faster than the careful reader, which still reads everything else and names
the cell that is wrong."""

from __future__ import annotations

import numpy as np

from thermal_comp.host.io.csv_format import TIME_UNITS, Source
from thermal_comp.host.io.plain_numbers import plain_numbers
from thermal_comp.host.io.run import TIME_COLUMN


def read_plain_table(src: Source) -> tuple[list[str], np.ndarray, np.ndarray] | None:
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
        data = plain_numbers(text, nl + 1, src.sep, len(header))
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
        data = plain_numbers("\n".join(body), 0, src.sep, len(header), len(body))
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


def _plain_result(src: Source, header: list[str], data: np.ndarray
                  ) -> tuple[list[str], np.ndarray, np.ndarray] | None:
    """The fast path's table (time in seconds, the file lines 2, 3, ...), None if a cell is
    infinite (the careful reader says where)."""
    if np.isinf(data).any():
        return None
    if src.time_unit is not None:
        data[:, header.index(TIME_COLUMN)] *= TIME_UNITS[src.time_unit]
    return header, data, np.arange(2, 2 + data.shape[0])

"""Interpolate short gaps in a run's columns when the caller allows it (``--fill-gaps``): a
logger drops a cell now and then, and a few interpolated samples cost the fit less than the
run; a longer gap, or one at either end, is refused naming its first cell."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from thermal_comp.host.io.format_error import RunFormatError


def filled_columns(path: Path, data: np.ndarray, lines: np.ndarray, col: Mapping[str, int],
                   names: list[str], time_s: np.ndarray, fill_gaps: int
                   ) -> tuple[dict[str, np.ndarray], int]:
    """Copies of the columns ``names`` with their gaps filled, and how many cells were; with
    ``fill_gaps`` 0 the first empty cell is refused."""
    filled = 0
    arrays: dict[str, np.ndarray] = {}
    for name in names:
        values = data[:, col[name]].copy()
        if np.isnan(values).any():
            if fill_gaps <= 0:
                i = int(np.flatnonzero(np.isnan(values))[0])
                raise RunFormatError(path, "empty or NaN cell (use --fill-gaps N to interpolate "
                                     "short gaps)", line=int(lines[i]), column=name)
            filled += _fill_gaps(path, name, values, time_s, fill_gaps, lines)
        arrays[name] = values
    return arrays, filled


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

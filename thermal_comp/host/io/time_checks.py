"""Check a run's time column: seconds, increasing, at one fixed period. The model's filters
and the box assume one sample every period, so time in ms, a gap or jitter would make the
lags wrong without a word; they are refused here, naming the line (a short gap may be filled).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from thermal_comp.host.io.format_error import RunFormatError
from thermal_comp.host.io.run import TIME_COLUMN

# A run's steps must be one period (the median step) within JITTER_TOLERANCE; a step beyond
# GAP_FACTOR periods is a gap (missing rows).
JITTER_TOLERANCE = 0.05
GAP_FACTOR = 1.5
MS_MIN_PERIOD = 100.0  # "seconds": time_s in ms has steps of 100..60000 for 0.1 s..1 min
MS_MIN_SPAN_S = 14 * 86400.0  # ... and spans months; a thermal test lasts hours to days.
# A step of a whole number of thousands (1000, 2000, 60000) is taken as whole seconds in ms
# too: a thermal test does not sample every 16.7 minutes on the dot.
# A time_s span beyond a year even when read as milliseconds is no thermal test in any unit
# (a 1e300 is a logger's error code, not milliseconds): refused as out of range.
MAX_SPAN_AS_MS = 366 * 86400.0 * 1000


def regular_time(path: Path, data: np.ndarray, lines: np.ndarray, time_col: int,
                 fill_gaps: int, guess: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The table's time column checked (present, increasing, seconds at one period; ``guess``
    False: its unit was given, no milliseconds guessed) and the table with NaN rows where
    ``fill_gaps`` allows to fill a gap: (data, lines, time_s)."""
    time_s = data[:, time_col].copy()
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
    fill = check_time(path, time_s, lines, fill_gaps, guess=guess)
    if fill:
        data, lines = _insert_rows(time_s, data, lines, fill, time_col)
        time_s = data[:, time_col].copy()
    return data, lines, time_s


def check_time(path: Path, time_s: np.ndarray, lines: np.ndarray, fill_gaps: int,
               guess: bool = True) -> list[tuple[int, int]]:
    """Refuse time in ms (unless its unit was given: ``guess`` False), gaps and jitter; return
    the gaps (row index, missing rows) that ``fill_gaps`` allows to fill."""
    steps = np.diff(time_s)
    if steps.size == 0:
        return []
    _refuse_beyond_a_year(path, time_s, lines)
    period = float(np.median(steps))
    if guess:
        _refuse_milliseconds(path, time_s, period)
    fill = _gaps_to_fill(path, time_s, lines, period, fill_gaps)
    _refuse_jitter(path, time_s, lines, period, fill)
    return fill


def _refuse_beyond_a_year(path: Path, time_s: np.ndarray, lines: np.ndarray) -> None:
    """A span no thermal test has in any unit: a logger's error code, not a time."""
    far = np.flatnonzero(np.abs(time_s - time_s[0]) > MAX_SPAN_AS_MS)
    if far.size:
        i = int(far[0])
        raise RunFormatError(
            path, f"time_s {time_s[i]:g} is out of range: {time_s[i] - time_s[0]:.3g} after "
            f"the first sample ({time_s[0]:g}), more than a year even if these were "
            "milliseconds (a thermal test run lasts hours to days; a logger's error code?)",
            line=int(lines[i]), column=TIME_COLUMN)


def _refuse_milliseconds(path: Path, time_s: np.ndarray, period: float) -> None:
    """Steps and a span that, read as seconds, no thermal test has: read as ms they fit."""
    span = float(time_s[-1] - time_s[0])
    whole_seconds_in_ms = period >= 1000 and abs(period / 1000 - round(period / 1000)) < 1e-9
    if (period >= MS_MIN_PERIOD and span >= MS_MIN_SPAN_S) or whole_seconds_in_ms:
        raise RunFormatError(
            path, f"time_s looks like milliseconds: steps of {period:g} and a span of "
            f"{span / 86400:.3g} days if these were seconds (a thermal test run lasts hours to "
            f"days); pass --time-unit ms to read it as milliseconds, or write time_s in seconds, "
            f"i.e. divide by 1000 (a step of {period / 1000:g} s, {span / 3600000:.3g} h); if "
            "these really are seconds, pass --time-unit s", column=TIME_COLUMN)


def _gaps_to_fill(path: Path, time_s: np.ndarray, lines: np.ndarray, period: float,
                  fill_gaps: int) -> list[tuple[int, int]]:
    """The gaps (row index, missing rows) ``fill_gaps`` allows to fill; the first other gap
    is refused with where to cut the run."""
    steps = np.diff(time_s)
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
    return fill


def _refuse_jitter(path: Path, time_s: np.ndarray, lines: np.ndarray, period: float,
                   fill: list[tuple[int, int]]) -> None:
    """Refuse steps off the period the timestamps imply, with that period to resample to."""
    steps = np.diff(time_s)
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

"""Cut a run into consecutive time windows, e.g. train on the first heat/cool cycles and test
on the last one (the FL_THERMAL run: 0-24 h = three cycles, 24-32 h = the 5000 rpm cycle).

Every column is kept as it is, including ``time_s`` (the parts are pieces of one run, not new
runs; model terms use sample counts, not the time column). A part's lag filters start cold at
its first sample when it is evaluated, as a box powered up at that moment would.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from thermal_comp.contract.errors import InputError
from thermal_comp.host.io.csv_format import CsvFormat
from thermal_comp.host.io.format_error import RunFormatError
from thermal_comp.host.io.run import TIME_COLUMN, Run
from thermal_comp.host.io.table import read_table
from thermal_comp.host.io.write import write_run


def _bounds(time_s: np.ndarray, at_s: list[float], where: str) -> list[tuple[int, int]]:
    cuts = sorted(float(a) for a in at_s)
    if not cuts:
        raise InputError(f"{where}: give at least one split time")
    idx = [int(np.searchsorted(time_s, c, side="left")) for c in cuts]
    edges = [0, *idx, len(time_s)]
    parts = list(zip(edges[:-1], edges[1:], strict=True))
    for (a, b), c in zip(parts[1:], cuts, strict=True):
        if b - a < 2 or parts[0][1] - parts[0][0] < 2:
            raise InputError(f"{where}: cutting at {c / 3600:g} h leaves a part with fewer than "
                             f"2 samples (run spans {time_s[0] / 3600:g}-{time_s[-1] / 3600:g} h)")
    return parts


def window(run: Run, start_s: float | None = None, stop_s: float | None = None) -> Run:
    """The part of a loaded run with start_s <= time_s < stop_s."""
    t = run.time_s
    a = 0 if start_s is None else int(np.searchsorted(t, start_s, side="left"))
    b = len(t) if stop_s is None else int(np.searchsorted(t, stop_s, side="left"))
    if b - a < 2:
        raise InputError(f"{run.path}: window {start_s}-{stop_s} s has fewer than 2 samples")
    part = run.slice(a, b)
    part.path = f"{run.path}[{t[a] / 3600:.4g}-{t[b - 1] / 3600:.4g}h]"
    return part


def split_file(path: str | Path, at_s: list[float], out_dir: str | Path,
               fmt: CsvFormat | None = None) -> list[Path]:
    """Write ``<stem>_<from>-<to>h.csv`` for each part of the CSV cut at ``at_s`` seconds.

    The parts are written in the project's format (``,``, decimal point, ``time_s`` in seconds,
    since the first sample when the file had timestamps); a gap in time is no reason to refuse:
    cutting there is what a gap calls for."""
    path = Path(path)
    header, data, _ = read_table(path, fmt)
    if TIME_COLUMN not in header:
        raise RunFormatError(path, f"missing column '{TIME_COLUMN}'", line=1, column=TIME_COLUMN)
    t = data[:, header.index(TIME_COLUMN)]
    if np.any(np.isnan(t)) or np.any(np.diff(t) <= 0):
        raise RunFormatError(path, "time_s must be present and strictly increasing to split",
                             column=TIME_COLUMN)
    parts = _bounds(t, at_s, str(path))
    edges_h = [t[0] / 3600, *(float(a) / 3600 for a in sorted(at_s)), t[-1] / 3600]
    out = []
    for i, (a, b) in enumerate(parts):
        name = f"{path.stem}_{edges_h[i]:.4g}-{edges_h[i + 1]:.4g}h.csv"
        target = Path(out_dir) / name
        cols = {h: data[a:b, j] for j, h in enumerate(header) if h != TIME_COLUMN}
        write_run(target, t[a:b], cols, precision=10)
        out.append(target)
    return out

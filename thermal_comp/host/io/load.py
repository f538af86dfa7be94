"""Load thermal test runs (CSV) into arrays, rejecting bad input with file, line and column.

A run is a CSV file with a header row: ``time_s`` (strictly increasing seconds at one fixed
period), temperature columns in degC, optional auxiliary columns (e.g. ``spindle_rpm``) and one
or more displacement columns in micrometres. Which column plays which role is decided by the
caller (``--target``, ``--sensors``, ``--aux``), never guessed from the values.

Loading is the order of the checks, each in its own module: the table (``table``, in the
dialect ``csv_format`` sniffs), the columns by role (``columns``), time (``time_checks``),
ranges (``value_ranges``), units (``unit_sniffing``), gaps (``gap_filling``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from thermal_comp.contract.tilt import Tilt, probe_columns
from thermal_comp.host.io.columns import sensor_columns
from thermal_comp.host.io.csv_format import CsvFormat
from thermal_comp.host.io.format_error import RunFormatError
from thermal_comp.host.io.gap_filling import filled_columns
from thermal_comp.host.io.run import TIME_COLUMN, Run
from thermal_comp.host.io.table import read_table
from thermal_comp.host.io.time_checks import regular_time
from thermal_comp.host.io.unit_sniffing import sniff_units
from thermal_comp.host.io.value_ranges import TARGET_LIMIT_UM, check_ranges, check_values


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
    sensor_names = sensor_columns(path, header, targets, aux, sensors, tilt_of, targets_from,
                                  sensors_from, aux_from)
    if data.shape[0] < min_samples:
        raise RunFormatError(path, f"{data.shape[0]} samples, the model needs at least "
                             f"{min_samples}")
    col = {name: header.index(name) for name in header}
    data, lines, time_s = regular_time(path, data, lines, col[TIME_COLUMN], fill_gaps,
                                       guess=fmt is None or fmt.time_unit is None)
    check_ranges(path, data, lines, col, sensor_names, targets, aux, fmt, temperature_ranges)
    sniff_units(path, time_s, {n: data[:, col[n]] for n in sensor_names},
                {n: data[:, col[n]] for n in targets}, fmt)
    arrays, filled = filled_columns(path, data, lines, col, [*sensor_names, *targets, *aux],
                                    time_s, fill_gaps)
    for name, tilt in tilt_of.items():
        arrays[name] = tilt.of(arrays[tilt.upper], arrays[tilt.lower])
        check_values(path, name, arrays[name], lines, -TARGET_LIMIT_UM, TARGET_LIMIT_UM,
                     f"urad is beyond any correction the box can output (±{TARGET_LIMIT_UM:g}"
                     f" urad): are the probes {tilt.distance_mm:g} mm apart, in micrometres?")
    return Run(str(path), time_s, sensor_names, _stack(arrays, sensor_names, len(time_s)),
               requested, _stack(arrays, requested, len(time_s)), aux,
               _stack(arrays, aux, len(time_s)) if aux else None, filled)


def _stack(arrays: Mapping[str, np.ndarray], names: list[str], n_samples: int) -> np.ndarray:
    """The columns ``names`` side by side, (n_samples, 0) for none."""
    if not names:
        return np.empty((n_samples, 0))
    return np.column_stack([arrays[n] for n in names])


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

"""Check a run's values against what the box can read and output: a temperature outside its
channel's range is a fault or a wrong unit, a displacement or aux value beyond int32 cannot
reach the box; each is refused naming its cell (with the unit it looks like, if one fits)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from thermal_comp.contract.box import CHANNEL_MAX_C, CHANNEL_MIN_C
from thermal_comp.contract.fixed_point import INT32_MAX
from thermal_comp.host.io.csv_format import DISP_UNITS, CsvFormat, to_celsius
from thermal_comp.host.io.format_error import RunFormatError

TARGET_LIMIT_UM = INT32_MAX / 1000  # the box's correction is int32 nanometres
AUX_LIMIT = float(INT32_MAX)  # the box's aux inputs are int32
DEFAULT_TEMPERATURE_RANGE = (CHANNEL_MIN_C, CHANNEL_MAX_C)


def check_ranges(path: Path, data: np.ndarray, lines: np.ndarray, col: Mapping[str, int],
                 sensor_names: list[str], targets: list[str], aux: list[str],
                 fmt: CsvFormat | None,
                 temperature_ranges: Mapping[str, tuple[float, float]] | None) -> None:
    """Convert the given units to degC and micrometres in place (``fmt``), then refuse the
    first value out of its range: temperatures by sensor (``temperature_ranges``, default
    the box's channel range), displacements and aux within int32."""
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
        check_values(path, name, data[:, col[name]], lines, -TARGET_LIMIT_UM, TARGET_LIMIT_UM,
                     f"um is beyond any correction the box can output (±{TARGET_LIMIT_UM:g} "
                     "um, int32 nanometres): a displacement column must be in micrometres")
    for name in aux:
        check_values(path, name, data[:, col[name]], lines, -AUX_LIMIT, AUX_LIMIT,
                     f"is beyond the box's int32 auxiliary input (±{AUX_LIMIT:g})")


def check_values(path: Path, name: str, values: np.ndarray, lines: np.ndarray, lo: float,
                 hi: float, what: str) -> None:
    """Refuse the first value outside lo..hi, ``what`` saying why the box cannot take it."""
    bad = np.flatnonzero((values < lo) | (values > hi))
    if not bad.size:
        return
    i = int(bad[0])
    raise RunFormatError(path, f"{values[i]:g} {what}", line=int(lines[i]), column=name)


def _check_temperatures(path: Path, name: str, values: np.ndarray, lines: np.ndarray,
                        lo: float, hi: float) -> None:
    """Refuse the first temperature outside lo..hi, with the unit the column looks like."""
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

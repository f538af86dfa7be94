"""Which column of a run plays which role is the caller's word (``--target``, ``--sensors``,
``--aux``), never guessed from the values; a column the caller names but the file lacks is
refused with the closest name the file has."""

from __future__ import annotations

import difflib
import fnmatch
from collections.abc import Mapping, Sequence
from pathlib import Path

from thermal_comp.contract.tilt import Tilt
from thermal_comp.host.io.format_error import RunFormatError
from thermal_comp.host.io.run import TIME_COLUMN


def sensor_columns(path: Path, header: list[str], targets: list[str], aux: list[str],
                   sensors: str | list[str], tilt_of: Mapping[str, Tilt], targets_from: str,
                   sensors_from: str, aux_from: str) -> list[str]:
    """The sensor columns (``sensors``: a glob or names), once the header is found to have
    the time column and every column the caller names (``*_from``: where the names come
    from, for the refusal)."""
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
        return sensor_names
    sensor_names = list(sensors)
    missing = [n for n in sensor_names if n not in header]
    if missing:
        raise RunFormatError(path, missing_sensors(
            missing, [h for h in header if h not in reserved], sensors_from), line=1)
    return sensor_names


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

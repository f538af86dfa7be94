"""Refuse a run that looks written in another unit than seconds, degC and micrometres
(minutes, degF, mm, nm): its values are in range, so only what a thermal test looks like
tells; the refusal says what it looks like and what to pass. A unit given is not guessed."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from thermal_comp.host.io.csv_format import CsvFormat
from thermal_comp.host.io.format_error import RunFormatError
from thermal_comp.host.io.run import TIME_COLUMN

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


def sniff_units(path: Path, time_s: np.ndarray, temps: Mapping[str, np.ndarray],
                disps: Mapping[str, np.ndarray], fmt: CsvFormat | None) -> None:
    """Refuse a run that looks written in another unit than seconds, degC and micrometres
    (minutes, degF, mm, nm), saying what it looks like and what to pass. Kelvin and
    milliseconds are out of range and refused where the range is checked."""
    fmt = fmt or CsvFormat()
    warming = {n: float(np.nanmax(v) - np.nanmin(v)) for n, v in temps.items()
               if np.isfinite(v).any()}
    hottest = max(warming, key=lambda n: warming[n]) if warming else None
    if fmt.time_unit is None and hottest is not None:
        _refuse_minutes(path, time_s, temps, hottest, warming[hottest])
    if fmt.temp_unit is None and len(temps) >= 2:
        _refuse_fahrenheit(path, temps)
    if fmt.disp_unit is None and disps:
        _refuse_other_lengths(path, disps, hottest, warming)


def _refuse_minutes(path: Path, time_s: np.ndarray, temps: Mapping[str, np.ndarray],
                    hottest: str, warmed: float) -> None:
    """A short run in which a sensor warms smoothly by degrees: minutes, not seconds."""
    span = float(time_s[-1] - time_s[0]) if time_s.size else 0.0
    period = float(np.median(np.diff(time_s))) if time_s.size > 1 else 0.0
    whole_s = 0 < period < 1 and abs(period * 60 - round(period * 60)) < 1e-6
    enough = time_s.size >= (MINUTES_MIN_SAMPLES // 2 if whole_s else MINUTES_MIN_SAMPLES)
    if enough and 0 < period <= 1.0 and 0 < span <= MINUTES_MAX_SPAN_S \
            and warmed >= MINUTES_MIN_WARMING_C:
        steps = np.abs(np.diff(temps[hottest]))
        if float(np.nanmedian(steps)) <= MINUTES_MAX_STEP_SHARE * warmed:
            raise RunFormatError(
                path, f"time_s looks like minutes: steps of {period:g} and a span of {span:g}, "
                f"{span / 60:.3g} min if these were seconds, while {hottest} changes by "
                f"{warmed:.3g} degC (a machine tool does not warm that fast; the "
                "lags' time constants would come out 60x too short); as minutes it is a step of "
                f"{period * 60:g} s and a run of {span / 60:.3g} h: pass --time-unit min to read "
                "it as minutes (or write time_s in seconds); if these really are seconds, pass "
                "--time-unit s", column=TIME_COLUMN)


def _refuse_fahrenheit(path: Path, temps: Mapping[str, np.ndarray]) -> None:
    """Every sensor warm for the whole run, the coolest too: degF, not degC."""
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


def _refuse_other_lengths(path: Path, disps: Mapping[str, np.ndarray], hottest: str | None,
                          warming: Mapping[str, float]) -> None:
    """Displacements moving by millimetres (nm) or not at all while the machine warms (mm)."""
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

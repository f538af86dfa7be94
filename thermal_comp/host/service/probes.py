"""Touch-probe readings of a run: synthesised from its measured displacement, or logged.

A probe reading at sample k is the axis's displacement since the reference as the probe sees
it: the run's measured target referenced the way the model's output is (``host evaluate``'s
``measured``), plus the probe's noise. In service a shop touches a reference artifact either
on a clock (``interval``: every DURATION) or only while the spindle stands (``stopped``: at a
tool change; the first standing sample once DURATION has passed since the last touch). One
touch cycle reads every axis at the same sample.

A run may instead carry the readings it logged, one sparse column per axis named
``probe_<axis>`` (``probe_dz_um``): an empty cell means no reading at that sample; every other
cell is a reading in the axis's unit, used as it is.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from thermal_comp.contract.errors import InputError
from thermal_comp.contract.model_file import OUTPUT_LIMIT_UM
from thermal_comp.host.io import CsvFormat, Run, RunFormatError, read_header, read_table

PROBE_WHEN = ("interval", "stopped")
PROBE_PREFIX = "probe_"
SPINDLE = "spindle_rpm"
STOPPED_RPM = 1.0  # |speed| at or below this: the spindle stands (a logger's zero may jitter)


class ProbeError(InputError):
    """Probe readings cannot be made or read as asked."""


def probe_column(axis: str) -> str:
    """The logged readings' column of ``axis``: ``probe_dz_um``."""
    return PROBE_PREFIX + axis


_DURATION = re.compile(r"^\s*([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*(s|sec|min|m|h|hr)?\s*$")
_UNIT_S = {None: 1.0, "s": 1.0, "sec": 1.0, "m": 60.0, "min": 60.0, "h": 3600.0, "hr": 3600.0}


def duration_s(text: str) -> float:
    """``--probe-every``: '60min', '2h', '90s', '3600' (seconds) to seconds; ProbeError if
    it is not a positive duration."""
    m = _DURATION.match(str(text))
    if not m:
        raise ProbeError(f"--probe-every: cannot read {text!r} as a duration (e.g. 30min, 2h, "
                         "900s)")
    seconds = float(m.group(1)) * _UNIT_S[m.group(2)]
    if not (math.isfinite(seconds) and seconds > 0):
        raise ProbeError(f"--probe-every: must be a positive duration (got {text!r})")
    return seconds


@dataclass(frozen=True)
class ProbePlan:
    """When a probe touches and how noisy it reads."""

    every_s: float
    noise_um: float = 0.5
    seed: int = 0
    when: str = "interval"
    stopped_rpm: float = STOPPED_RPM

    def __post_init__(self) -> None:
        if not (math.isfinite(self.every_s) and self.every_s > 0):
            raise ProbeError(f"--probe-every: must be a positive duration (got {self.every_s!r} s)")
        if not (math.isfinite(self.noise_um) and self.noise_um >= 0):
            raise ProbeError(f"--probe-noise-um: must be 0 or more (got {self.noise_um!r})")
        if self.when not in PROBE_WHEN:
            raise ProbeError(f"--probe-when: {self.when!r} is not one of {', '.join(PROBE_WHEN)}")

    def describe(self) -> str:
        when = "while the spindle stands" if self.when == "stopped" else "on the clock"
        return (f"every {self.every_s / 60:g} min {when}, noise {self.noise_um:g} um, "
                f"seed {self.seed}")


@dataclass
class ProbeReadings:
    """Readings per axis: sample indices (increasing) and values (axis unit)."""

    index: dict[str, np.ndarray] = field(default_factory=dict)
    value: dict[str, np.ndarray] = field(default_factory=dict)
    source: str = ""  # "synthesised: ..." or "logged: probe_dz_um, ..."

    def count(self, axis: str) -> int:
        return int(self.index[axis].size) if axis in self.index else 0


def probe_samples(run: Run, plan: ProbePlan) -> np.ndarray:
    """The sample indices a plan touches at (never sample 0: that is the reference)."""
    t = run.time_s
    if plan.when == "stopped":
        if SPINDLE not in run.aux_names:
            raise ProbeError(f"{run.path}: --probe-when stopped needs the '{SPINDLE}' column "
                             f"(pass --aux {SPINDLE} when training, or use --probe-when "
                             "interval)")
        standing = np.abs(run.column(SPINDLE)) <= plan.stopped_rpm
    else:
        standing = np.ones(t.size, dtype=bool)
    out: list[int] = []
    due = t[0] + plan.every_s
    k = 1
    while k < t.size:
        k = int(np.searchsorted(t, due - 1e-9 * plan.every_s, side="left"))
        k = max(k, 1)
        while k < t.size and not standing[k]:
            k += 1
        if k >= t.size:
            break
        out.append(k)
        due = t[k] + plan.every_s
        k += 1
    return np.asarray(out, dtype=int)


def synthesise_probes(run: Run, truth: Mapping[str, np.ndarray], plan: ProbePlan
                      ) -> ProbeReadings:
    """Readings of every axis of ``truth`` (the measured displacement since the reference,
    per axis) at the plan's samples, plus Gaussian noise of ``plan.noise_um`` drawn from
    ``plan.seed`` (one draw per touch and axis, in the order of ``truth``)."""
    idx = probe_samples(run, plan)
    noise = np.random.default_rng(plan.seed).normal(0.0, 1.0, (idx.size, len(truth)))
    out = ProbeReadings(source=f"synthesised: {plan.describe()}")
    for j, (axis, y) in enumerate(truth.items()):
        out.index[axis] = idx.copy()
        out.value[axis] = np.asarray(y, dtype=float)[idx] + plan.noise_um * noise[:, j]
    return out


def logged_columns(path: str | Path, axes: Sequence[str], fmt: CsvFormat | None = None
                   ) -> list[str]:
    """The ``probe_<axis>`` columns a run file carries for ``axes``."""
    header = read_header(path, fmt)
    return [a for a in axes if probe_column(a) in header]


def logged_probes(path: str | Path, run: Run, axes: Sequence[str],
                  fmt: CsvFormat | None = None) -> ProbeReadings:
    """The readings a run file logged in its sparse ``probe_<axis>`` columns, used as they
    are; an axis without such a column has none. A cell that is not a number, or beyond the
    box's int32 nanometres, is refused naming file, line and column; a reading at a time the
    run does not hold (a window of it) is left out."""
    header, data, lines = read_table(path, fmt)
    out = ProbeReadings()
    found = []
    time = data[:, header.index("time_s")] if "time_s" in header else None
    for axis in axes:
        name = probe_column(axis)
        if name not in header:
            continue
        if time is None:
            raise RunFormatError(path, "missing column 'time_s'", line=1, column="time_s")
        values = data[:, header.index(name)]
        rows = np.flatnonzero(~np.isnan(values))
        big = rows[np.abs(values[rows]) > OUTPUT_LIMIT_UM]
        if big.size:
            raise RunFormatError(path, f"probe reading {values[big[0]]:g} is beyond any "
                                 f"correction the box can output (±{OUTPUT_LIMIT_UM:g}, int32 "
                                 "nanometres): a probe column must be in the axis's unit "
                                 "(um)", line=int(lines[big[0]]), column=name)
        k = np.searchsorted(run.time_s, time[rows])
        inside = k < run.n_samples
        inside[inside] &= np.abs(run.time_s[k[inside]] - time[rows][inside]) \
            <= 1e-6 * max(run.period_s, 1e-9)
        out.index[axis] = k[inside].astype(int)
        out.value[axis] = values[rows][inside].astype(float)
        found.append(name)
    out.source = f"logged: {', '.join(found)}" if found else "logged: none"
    return out


def any_logged(path: str | Path, axes: Sequence[str], fmt: CsvFormat | None = None) -> bool:
    return bool(logged_columns(path, axes, fmt))

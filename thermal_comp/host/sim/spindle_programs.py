"""Spindle programs of a thermal test: spindle speed against time, shared by simulate and testplan.

A program is a list of segments of constant speed (what an NC program does with S words), a
running phase followed by a cooling phase at standstill. ``host simulate`` drives the thermal
model with it and ``host testplan`` writes it as G-code, so the machine runs exactly the
schedule that was simulated.

Protocols (paper 002 and ISO 230-3 practice; paper 000 for ``sine``):
  constant  one level, 75 % of max speed by default (ISO 230-3's constant-speed test)
  step      25/50/75/100 % of max, 15 min each, repeated until the running phase ends
  random    levels 0/25/50/75/100 % for 5..30 min each, drawn with a seed: an ISO 230-3-like
            speed spectrum whose mean (about 50 %) is lower than the constant test, as in
            paper 002's Fig. 3. Not the standard's own table (which we don't reproduce).
  sine      sinusoidal speed between ``sine_min_fraction`` and 100 %, 1 h period (paper 000:
            50..3000 rpm), held in 60 s stairs because a CNC changes speed by S words
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from thermal_comp.contract.errors import InputError

PROTOCOLS = ("constant", "step", "random", "sine")
RUN, COOL = "run", "cool"

STEP_LEVELS = (0.25, 0.50, 0.75, 1.00)
RANDOM_LEVELS = (0.0, 0.25, 0.50, 0.75, 1.00)
RANDOM_WEIGHTS = (0.10, 0.30, 0.25, 0.20, 0.15)
RANDOM_MINUTES = (5, 10, 15, 20, 30)
SINE_MIN_FRACTION = 50.0 / 3000.0  # paper 000: 50..3000 rpm


class ProgramError(InputError):
    """A spindle program cannot be built as asked (bad speed, duration or protocol)."""


@dataclass(frozen=True)
class Segment:
    """Constant spindle speed for a while; ``phase`` is ``run`` or ``cool``."""

    start_s: float
    duration_s: float
    rpm: float
    phase: str = RUN

    @property
    def end_s(self) -> float:
        return self.start_s + self.duration_s


@dataclass(frozen=True)
class SpindleProgram:
    """Spindle speed against time: contiguous segments starting at t = 0."""

    protocol: str
    max_rpm: float
    segments: tuple[Segment, ...]
    params: dict = field(default_factory=dict)

    @property
    def duration_s(self) -> float:
        return self.segments[-1].end_s if self.segments else 0.0

    @property
    def run_s(self) -> float:
        return sum(s.duration_s for s in self.segments if s.phase == RUN)

    def boundaries_s(self) -> np.ndarray:
        """Start of every segment and the end of the last one."""
        return np.array([s.start_s for s in self.segments] + [self.duration_s])

    @cached_property
    def _table(self) -> tuple[np.ndarray, np.ndarray]:
        return (np.array([s.start_s for s in self.segments]),
                np.array([s.rpm for s in self.segments] + [0.0]))

    def rpm_at(self, t_s: np.ndarray | float) -> np.ndarray:
        """Speed at times t (right-continuous: a change at t applies from t on; 0 after the end)."""
        t = np.asarray(t_s, dtype=float)
        starts, rpms = self._table
        idx = np.searchsorted(starts, t, side="right") - 1
        idx = np.where(t >= self.duration_s, len(self.segments), idx)
        return np.where(idx < 0, 0.0, rpms[np.clip(idx, 0, len(self.segments))])

    def mean_run_fraction(self) -> float:
        """Time-averaged speed of the running phase as a fraction of max speed."""
        run = [s for s in self.segments if s.phase == RUN]
        total = sum(s.duration_s for s in run)
        return sum(s.rpm * s.duration_s for s in run) / (total * self.max_rpm) if total else 0.0

    def to_json(self) -> dict:
        return {"protocol": self.protocol, "max_rpm": self.max_rpm, **self.params,
                "segments": [[s.start_s, s.duration_s, s.rpm, s.phase] for s in self.segments]}


def _check_level(rpm: float, max_rpm: float, what: str) -> None:
    if not math.isfinite(rpm) or rpm < 0:
        raise ProgramError(f"{what}: speed {rpm:g} rpm is not a valid spindle speed")
    if rpm > max_rpm + 1e-9:
        raise ProgramError(f"{what}: speed {rpm:g} rpm is above --max-rpm {max_rpm:g}")


def _merge(pieces: list[tuple[float, float]], phase: str, t0: float) -> list[Segment]:
    """(duration, rpm) pieces to contiguous segments, merging neighbours of equal speed."""
    out: list[Segment] = []
    t = t0
    for duration, rpm in pieces:
        if duration <= 0:
            continue
        if out and out[-1].rpm == rpm and out[-1].phase == phase:
            last = out.pop()
            out.append(Segment(last.start_s, last.duration_s + duration, rpm, phase))
        else:
            out.append(Segment(t, duration, rpm, phase))
        t += duration
    return out


def _fill(levels: list[tuple[float, float]], run_s: float) -> list[tuple[float, float]]:
    """Repeat (duration, rpm) pieces until run_s is filled; the last piece is cut to fit."""
    out: list[tuple[float, float]] = []
    t = 0.0
    i = 0
    while t < run_s - 1e-9:
        duration, rpm = levels[i % len(levels)]
        duration = min(duration, run_s - t)
        out.append((duration, rpm))
        t += duration
        i += 1
    return out


def build_program(protocol: str, max_rpm: float = 8000.0, hours: float = 8.0,
                  cool_hours: float = 8.0, seed: int = 0, *, rpm: float | None = None,
                  levels: tuple[float, ...] | None = None, step_minutes: float = 15.0,
                  sine_period_h: float = 1.0, sine_min_fraction: float = SINE_MIN_FRACTION,
                  sine_stair_s: float = 60.0) -> SpindleProgram:
    """The spindle program of one protocol: ``hours`` of running, then ``cool_hours`` at rest.

    ``rpm`` sets the constant level (default 75 % of ``max_rpm``); ``levels`` (fractions of
    max speed) replace the step / random levels. Speeds are whole rpm, as S words are.
    """
    _check_program(protocol, max_rpm, hours, cool_hours, levels)
    run_s = hours * 3600.0
    params: dict = {"hours": hours, "cool_hours": cool_hours}
    if protocol == "constant":
        pieces = _constant_pieces(run_s, max_rpm, rpm, params)
    elif protocol == "step":
        pieces = _step_pieces(run_s, max_rpm, levels or STEP_LEVELS, step_minutes, params)
    elif protocol == "random":
        pieces = _random_pieces(run_s, max_rpm, levels, seed, params)
    else:
        pieces = _sine_pieces(run_s, max_rpm, sine_period_h, sine_min_fraction, sine_stair_s,
                              params)
    segments = _merge(pieces, RUN, 0.0)
    if cool_hours > 0:
        segments += _merge([(cool_hours * 3600.0, 0.0)], COOL, run_s)
    return SpindleProgram(protocol, float(max_rpm), tuple(segments), params)


def _check_program(protocol: str, max_rpm: float, hours: float, cool_hours: float,
                   levels: tuple[float, ...] | None) -> None:
    if protocol not in PROTOCOLS:
        raise ProgramError(f"unknown protocol '{protocol}' (known: {', '.join(PROTOCOLS)})")
    if not (math.isfinite(max_rpm) and max_rpm > 0):
        raise ProgramError(f"--max-rpm must be positive (got {max_rpm:g})")
    if not (math.isfinite(hours) and hours > 0):
        raise ProgramError(f"--hours must be positive (got {hours:g})")
    if not (math.isfinite(cool_hours) and cool_hours >= 0):
        raise ProgramError(f"--cool-hours must be zero or positive (got {cool_hours:g})")
    if levels is not None:
        for f in levels:
            _check_level(f * max_rpm, max_rpm, f"level {100 * f:g} %")


# The running part of each protocol as (duration, rpm) pieces; each records its parameters.

def _constant_pieces(run_s: float, max_rpm: float, rpm: float | None, params: dict
                     ) -> list[tuple[float, float]]:
    level = round(0.75 * max_rpm) if rpm is None else float(rpm)
    _check_level(level, max_rpm, "constant speed (--rpm)")
    params["rpm"] = float(level)
    return [(run_s, float(level))]


def _step_pieces(run_s: float, max_rpm: float, fracs: tuple[float, ...], step_minutes: float,
                 params: dict) -> list[tuple[float, float]]:
    if step_minutes <= 0:
        raise ProgramError(f"step length must be positive (got {step_minutes:g} min)")
    params.update(levels=list(fracs), step_minutes=step_minutes)
    return _fill([(step_minutes * 60.0, float(round(f * max_rpm))) for f in fracs], run_s)


def _random_pieces(run_s: float, max_rpm: float, levels: tuple[float, ...] | None, seed: int,
                   params: dict) -> list[tuple[float, float]]:
    """Seeded levels and durations; a new level each time, as the random test changes speed."""
    fracs = levels or RANDOM_LEVELS
    weights = np.array(RANDOM_WEIGHTS if levels is None else [1.0] * len(fracs), float)
    rng = np.random.default_rng(seed)
    pieces = []
    t, last = 0.0, -1
    while t < run_s - 1e-9:
        choice = int(rng.choice(len(fracs), p=weights / weights.sum()))
        if choice == last and len(fracs) > 1:
            continue
        minutes = float(rng.choice(RANDOM_MINUTES))
        duration = min(minutes * 60.0, run_s - t)
        pieces.append((duration, float(round(fracs[choice] * max_rpm))))
        t += duration
        last = choice
    params.update(levels=list(fracs), seed=seed, minutes=list(RANDOM_MINUTES))
    return pieces


def _sine_pieces(run_s: float, max_rpm: float, period_h: float, min_fraction: float,
                 stair_s: float, params: dict) -> list[tuple[float, float]]:
    """A raised cosine from ``min_fraction`` to full speed, in stairs of ``stair_s``."""
    if not 0 <= min_fraction < 1:
        raise ProgramError(f"sine minimum must be in [0, 1) of max speed "
                           f"(got {min_fraction:g})")
    if stair_s <= 0 or period_h <= 0:
        raise ProgramError("sine period and stair length must be positive")
    period_s = period_h * 3600.0
    n = math.ceil(run_s / stair_s - 1e-9)
    pieces = []
    for k in range(n):
        duration = min(stair_s, run_s - k * stair_s)
        mid = k * stair_s + 0.5 * duration
        frac = min_fraction + (1 - min_fraction) * 0.5 * (
            1 - math.cos(2 * math.pi * mid / period_s))
        pieces.append((duration, float(round(frac * max_rpm))))
    params.update(period_h=period_h, min_fraction=min_fraction, stair_s=stair_s)
    return pieces

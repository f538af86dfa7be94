"""Candidate effect families: what the box could add to an axis, given its terms.

Part of closing the loop (docs/effects.md); host.effects.search drives the steps.
"""

from __future__ import annotations

import fnmatch
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from thermal_comp.contract.errors import InputError
from thermal_comp.contract.terms import (
    Term,
    make_lag,
    make_rate,
    make_speed,
    make_square,
    make_temp,
    make_time,
)
from thermal_comp.host.io import Run

# Time constants tried for lag/rate/ambient: minutes to hours. The longest (4 h) keeps the
# state-quantisation bound (0.5/alpha state units) small at the usual sample periods (>= 1 s);
# a model that would still break the codegen bound is refused candidate by candidate.
TAU_GRID_S = (300.0, 600.0, 1200.0, 1800.0, 3600.0, 7200.0, 14400.0)
MIN_TAU_SAMPLES = 3  # a filter faster than three samples is the sensor itself
MAX_TAU_RUN_FRACTION = 0.25  # a run must span 4 time constants (98 % settled) to identify one
AMBIENT_PATTERNS = ("*amb*", "*AMB*", "*Amb*")
class EffectsError(InputError):
    """The effect search cannot run on these inputs (names the column or parameter)."""




@dataclass(frozen=True)
class Candidate:
    """One effect family: terms to add (and, for a swap, terms to remove).

    ``family`` is set when the candidate also re-selects the temperature sensors (an input's
    family, see ``reselected_candidates``): ``add`` then holds the family *and* the newly
    selected sensors, ``remove`` the sensors the re-selection gave up, and the effect itself
    (its evidence, its contribution) is ``family`` alone.
    """

    kind: str
    add: tuple[Term, ...]
    remove: tuple[Term, ...] = ()
    family: tuple[Term, ...] = ()

    @property
    def effect_terms(self) -> tuple[Term, ...]:
        return self.family or self.add

    @property
    def n_terms(self) -> int:
        """Terms the model gains (a re-selection may also give some up)."""
        return len(self.add) - len(self.remove)

    @property
    def feature(self) -> str:
        if self.family:
            moved = ([f"+{t.source}" for t in self.add if t not in self.family]
                     + [f"-{t.source}" for t in self.remove])
            return (f"{' + '.join(t.name for t in self.family)} "
                    f"(sensors re-selected: {', '.join(moved)})")
        text = " + ".join(t.name for t in self.add)
        if self.remove:
            text = f"{text} instead of {' + '.join(t.name for t in self.remove)}"
        return text

    def apply(self, terms: Sequence[Term]) -> list[Term]:
        return [t for t in terms if t not in self.remove] + [t for t in self.add
                                                              if t not in terms]


def find_ambient(sensor_names: Sequence[str], ambient: str | None = None) -> str | None:
    """The ambient sensor: the one given (must be a sensor column), else a name like *amb*."""
    if ambient is not None:
        if ambient not in sensor_names:
            raise EffectsError(f"--ambient {ambient}: not one of the temperature columns "
                               f"({', '.join(sensor_names)}); make --sensors include it")
        return ambient
    for name in sensor_names:
        if any(fnmatch.fnmatchcase(name, p) for p in AMBIENT_PATTERNS):
            return name
    return None


def tau_grid(period_s: float, shortest_run_s: float,
             taus: Iterable[float] = TAU_GRID_S) -> list[float]:
    """Time constants that are identifiable at this period and run length."""
    return [float(t) for t in taus
            if t >= MIN_TAU_SAMPLES * period_s and t <= MAX_TAU_RUN_FRACTION * shortest_run_s]


def start_reference(runs: Sequence[Run], sensor: str) -> float:
    """Reference of a ``square`` term: the median start temperature of the runs."""
    return float(np.median([r.column(sensor)[0] for r in runs]))


def generate_candidates(current: Sequence[Term], sensors: Sequence[str], aux: Sequence[str],
                        ambient: str | None, period_s: float, taus: Sequence[float],
                        square_refs: Mapping[str, float]) -> list[Candidate]:
    """Every effect family the box can compute, given the current terms.

    - lag: lag(s, tau) of every sensor (a selected sensor's own lag models its pseudo-
      hysteresis; another sensor's lag stands in for an unmeasured part);
    - rate: rate(s, tau) of sensors whose temperature is not a term (for those that are,
      rate = T - lag spans the same model as lag and is reported as lag);
    - ambient: the ambient sensor, its lag (the frame follows the air through a first-order
      lag), and both (a part that follows the air at once plus one that lags);
    - speed: n, and n with n^2, of every aux input (no lag: immediate growth);
    - drift: a slow trend (``time``);
    - nonlinear: (T - T_start)^2 of a sensor that is a term, or T and (T - T_start)^2 of one
      that is not.
    """
    have = set(current)
    temps = {t.source for t in current if t.kind == "temp"}
    out: list[Candidate] = []

    def add(kind: str, *terms: Term) -> None:
        if not any(t in have for t in terms):
            out.append(Candidate(kind, tuple(terms)))

    for s in sensors:
        if s == ambient:
            continue
        for tau in taus:
            add("lag", make_lag(s, tau, period_s))
        if s not in temps:
            for tau in taus:
                add("rate", make_rate(s, tau, period_s))
    if ambient is not None:
        if ambient not in temps:
            add("ambient", make_temp(ambient))
            for tau in taus:
                add("ambient", make_temp(ambient), make_lag(ambient, tau, period_s))
        else:
            for tau in taus:
                add("ambient", make_lag(ambient, tau, period_s))
    for n in aux:
        add("speed", make_speed(n))
        add("speed", make_speed(n), make_speed(n, squared=True))
    add("drift", make_time())
    for s in sensors:
        if s == ambient or s not in square_refs:
            continue
        if s in temps:
            add("nonlinear", make_square(s, square_refs[s]))
        else:
            add("nonlinear", make_temp(s), make_square(s, square_refs[s]))
    return out

"""The ridge family: an axis's terms plus lags of every sensor it reads, within the box.

The ridge reads every wired thermocouple: the sensors the axes selected plus, up to the
channel budget, the best of the others by an L1 ranking (host.train.free_channels), so the
box's free inputs are not left unused. It is fitted by a ridge whose penalty is chosen out of
fold and weighs every um/K alike (host.fitting.ridge), to its rows low-passed
(host.fitting.prefilter: the probes' and thermocouples' noise out of the fit). Its lags spend
filter states, shared on the box by every term of one sensor and time constant: at most
``contract.box.BOX_STATES`` distinct ones over all axes (shared_lag_budget), and its
coefficients must keep codegen's fixed-point bound (host.effects.fixed_point_refusal); lags
are given up, longest first, until both hold.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

from thermal_comp.contract.box import BOX_STATES
from thermal_comp.contract.terms import (
    FILTER_KINDS,
    KELVIN_KINDS,
    Term,
    filter_states,
    make_lag,
    make_speed,
    make_temp,
    term_sensors,
)
from thermal_comp.host.effects import fixed_point_refusal, tau_grid
from thermal_comp.host.fitting import Reference, fit_ridge, penalty_groups, stack
from thermal_comp.host.fitting.prefilter import PREFILTER_TAU_S, prefiltered
from thermal_comp.host.io import Run
from thermal_comp.host.train.axis_fit import AxisFit

LAG_TAUS_S = (900.0, 3600.0)  # a fast and a slow part of the structure behind each sensor
# a bending axis's ridge: the response to an even, settled warming (the sum of its temperature
# and lag coefficients) costs this many times one coefficient; 1 / 3 / 10 / 30 measured on
# both simulators' column-bending dy, 3 the highest before the project simulator's dy (whose
# frame does respond to an even warming a little) lost (docs/training.md)
EVEN_WARMING_PENALTY = 3.0
EVEN_WARMING_KINDS = ("temp", "lag")  # a rate settles to zero: no part of the settled sum
# effects whose filter the ridge leaves to its own lags of the effect's sensor (ridge_start)
LAG_FAMILY_KINDS = ("lag", "rate")


@dataclass(frozen=True)
class RidgeOptions:
    """How an axis's ridge is fitted beyond its basis: ``bending``, its response to an even
    warming penalised too (EVEN_WARMING_PENALTY; docs/training.md, the bending axis), and
    ``prefilter_s``, the low-pass its rows are fitted through (host.fitting.prefilter; 0: the
    raw rows, as before main 4102d6e)."""

    bending: bool = False
    prefilter_s: float = PREFILTER_TAU_S


DEFAULT_RIDGE = RidgeOptions()


def lag_family_filters(effects: Sequence[dict]) -> list[Term]:
    """The lags and rates that lag and rate effects added, in the effects' order."""
    return [Term.from_json(t) for e in effects if e.get("kind") in LAG_FAMILY_KINDS
            for t in e.get("added", []) if t["kind"] in FILTER_KINDS]


def lag_taus(runs: Sequence[Run], period_s: float) -> list[float]:
    """The ridge's lag time constants that the shortest run identifies."""
    return tau_grid(period_s, min(r.time_s[-1] - r.time_s[0] for r in runs), LAG_TAUS_S)


def fastest_lag_s(runs: Sequence[Run], period_s: float) -> float:
    """The ridge's fastest lag time constant on these runs (inf: its basis has no lags)."""
    taus = lag_taus(runs, period_s)
    return min(taus) if taus else math.inf


def reading(terms: Sequence[Term], sensors: Sequence[str]) -> list[Term]:
    """The terms plus the temperature of every sensor in ``sensors`` they do not read yet."""
    have = set(term_sensors(terms))
    return list(terms) + [make_temp(s) for s in sensors if s not in have]


def ridge_start(terms: Sequence[Term], effects: Sequence[dict], fastest_s: float
                ) -> list[Term]:
    """The terms the ridge starts from: ``terms`` without the filters that lag and rate
    effects added with a time constant the ridge's own lags cover (at least its fastest,
    ``fastest_s``: fastest_lag_s), each such effect's sensor still read.

    The ridge's basis has lags of every sensor it reads, so a slower thermal lag is a blend
    of what it has already; a faster one is not. Beside those lags, the effect's own slower
    filter was neutral to harmful on unseen runs: of 142 bench cases the model was worse than
    without its effects by more than 5 % in 10, each with a lag or rate of 1,200 s or slower
    (docs/training.md). The effect stays named in the report, with its evidence."""
    added = [t for t in lag_family_filters(effects) if t.params["tau_s"] >= fastest_s]
    kept = [t for t in terms if t not in added]
    return reading(kept, [s for s in term_sensors(added) if s in term_sensors(terms)])


def pool_lags(sensors: Sequence[str], taus: Sequence[float], period_s: float) -> list[Term]:
    """First-order lags of every sensor at each time constant, the fastest first."""
    return [make_lag(s, tau, period_s) for tau in taus for s in sensors]


def pool_depth(terms: Sequence[Term], sensors: Sequence[str], taus: Sequence[float],
               period_s: float, max_states: int) -> int:
    """How many of ``taus`` (fastest first) the lags of ``sensors`` may use beside ``terms``
    within ``max_states`` distinct filters (contract.terms.filter_states)."""
    return max((k for k in range(len(taus) + 1)
                if filter_states([*terms, *pool_lags(sensors, taus[:k], period_s)])
                <= max_states), default=0)


def ridge_basis(terms: Sequence[Term], aux: Sequence[str], period_s: float,
                shortest_s: float, max_states: int, also: Sequence[str] = ()) -> list[Term]:
    """The terms, the temperature of each sensor in ``also`` they do not read, lags of every
    sensor read (as many time constants as ``max_states`` distinct filters allow, fastest
    first) and the speed of every aux input."""
    out = reading(terms, also)
    sensors = term_sensors(out)
    taus = tau_grid(period_s, shortest_s, LAG_TAUS_S)
    n_lags = pool_depth(out, sensors, taus, period_s, max_states)
    for lag in pool_lags(sensors, taus[:n_lags], period_s):
        if lag not in out:
            out.append(lag)
    for name in aux:
        speed = make_speed(name)
        if speed not in out:
            out.append(speed)
    return out


def fit_ridge_terms(runs: Sequence[Run], target: str, terms: Sequence[Term], period_s: float,
                    n_blocks: int, reference: Reference, ridge: RidgeOptions = DEFAULT_RIDGE):
    """The ridge of one axis over ``terms``, its temperature-like terms penalised in kelvin,
    fitted to the rows prefiltered (``ridge.prefilter_s``, host.fitting.prefilter) and its
    penalty chosen on host.fitting.penalty_groups (the stack carries those folds), scored on
    the raw rows. ``ridge.bending``: the axis's response to an even warming is penalised too
    (EVEN_WARMING_PENALTY; host.fitting.ridge)."""
    st = stack(list(runs), list(terms), target, period_s, n_blocks, reference)
    groups, scheme = penalty_groups(list(runs), n_blocks)
    st = replace(st, groups=groups, scheme=scheme)
    even = [t.kind in EVEN_WARMING_KINDS for t in terms] if ridge.bending else None
    slow = (prefiltered(st.X, st.y, [r.n_samples for r in runs], period_s, ridge.prefilter_s)
            if ridge.prefilter_s > 0 else None)
    return fit_ridge(st.X, st.y, st.groups, shared=[t.kind in KELVIN_KINDS for t in terms],
                     even=even, even_penalty=EVEN_WARMING_PENALTY if ridge.bending else 0.0,
                     fit_on=slow), st


def ridge_axis(runs: Sequence[Run], target: str, terms: Sequence[Term], *, aux: Sequence[str],
               period_s: float, n_blocks: int, reference: Reference,
               max_states: int, also: Sequence[str] = (),
               ridge: RidgeOptions = DEFAULT_RIDGE
               ) -> tuple[list[Term], object, object] | None:
    """The ridge family fitted on all runs (reading the sensors ``also`` too), within the box's
    states and fixed-point bound (None when not even the terms and temperatures alone fit:
    then the box keeps the least-squares model)."""
    shortest = min(r.time_s[-1] - r.time_s[0] for r in runs)
    tried: list[Term] | None = None
    for states in range(max_states, -1, -1):
        basis = ridge_basis(terms, aux, period_s, shortest, states, also)
        if basis == tried:
            continue  # one state fewer, the same lags: the same fit, refused already
        tried = basis
        fit, st = fit_ridge_terms(runs, target, basis, period_s, n_blocks, reference, ridge)
        if fixed_point_refusal(basis, fit.coef) is None:
            return basis, fit, st
        if not any(t.kind in FILTER_KINDS for t in basis if t not in terms):
            return None
    return None


def ridge_axis_fit(basis: list[Term], fit, st) -> AxisFit:
    """The axis fit of a ridge (the same metrics as a least-squares axis)."""
    return AxisFit.of(basis, fit.coef, fit.intercept, st.X, st.y, fit.validation_rmse_um,
                      st.scheme)


def shared_lag_budget(axes_terms: Sequence[Sequence[Term]], read: Sequence[str],
                      runs: Sequence[Run], period_s: float) -> dict[int, int]:
    """Each axis's filter budget for its ridge (by position in ``axes_terms``): its own terms
    plus the lags of the sensors ``read`` at as many time constants as the box's
    ``BOX_STATES`` allow over all axes. The box shares one filter state between the terms of
    one sensor and time constant on every axis (contract.terms.filter_states), so a lag pool
    over the wired sensors costs its states once, however many axes read it."""
    shortest = min(r.time_s[-1] - r.time_s[0] for r in runs)
    taus = tau_grid(period_s, shortest, LAG_TAUS_S)
    every = [t for terms in axes_terms for t in terms]
    pool = pool_lags(read, taus[:pool_depth(every, read, taus, period_s, BOX_STATES)], period_s)
    return {i: filter_states([*terms, *pool]) for i, terms in enumerate(axes_terms)}

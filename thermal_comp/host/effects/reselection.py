"""Families of a measured input, scored with the sensors re-selected given that input.

Part of closing the loop (docs/effects.md); host.effects.search drives the steps.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from thermal_comp.contract.terms import Term, make_temp, term_sensors
from thermal_comp.host.effects.candidates import Candidate
from thermal_comp.host.effects.scoring import FeatureCache, GramScorer
from thermal_comp.host.selection import DEFAULT_GROUPS, DEFAULT_MAX_SENSORS, select_sensors

# Families of a measured input (shop air, spindle speed): the static selection may have picked
# stand-ins for them, so they are also tried with the sensors re-selected (docs/effects.md).
INPUT_KINDS = ("ambient", "speed")


@dataclass(frozen=True)
class Reselection:
    """How the baseline's sensors were selected, so an input's family can redo it.

    Same method and group count as host.train's selection (from its trace); ``max_sensors``
    is the most sensors a re-selection may keep.
    """

    method: str = "validated"
    n_groups: int = DEFAULT_GROUPS
    max_sensors: int = DEFAULT_MAX_SENSORS
    seed: int = 0

    @classmethod
    def from_trace(cls, trace: Mapping | None, max_sensors: int = DEFAULT_MAX_SENSORS
                   ) -> Reselection:
        trace = trace or {}
        groups = trace.get("groups") or []
        return cls(method=str(trace.get("method", "validated")),
                   n_groups=len(groups) or DEFAULT_GROUPS, max_sensors=int(max_sensors))


def input_source(cand: Candidate) -> str | None:
    """The measured input an input family is built on (the ambient sensor, an aux column)."""
    if cand.kind not in INPUT_KINDS or cand.remove or cand.family:
        return None
    return str(cand.add[0].source)


def reselected_candidates(cands: Sequence[Candidate], cache: FeatureCache, y: np.ndarray,
                          groups: np.ndarray, run_ids: np.ndarray, current: Sequence[Term],
                          sensors: Sequence[str], ambient: str | None, period_s: float,
                          scheme: str, how: Reselection, allowed_new: int,
                          baseline_sources: set[str]) -> list[Candidate]:
    """An input's family with the temperature sensors selected again, given that input.

    The air and the spindle speed reach the whole machine. A static selection, which sees
    only temperatures, therefore picks thermocouples that stand in for them (the table and
    the tank for the air's slow pull on the frame, a fast gearbox sensor for the spindle's
    speed), and adding the input's own terms to that model leaves the stand-ins in it: they
    are fitted to this run's coincidences and cost accuracy on another day. Per input
    (the ambient sensor, every aux column) this takes the variant of its family that best
    explains the target together with *every* thermocouple (no stand-in is needed there),
    removes it and the model's other effect terms from the target and the temperatures
    (Frisch-Waugh-Lovell), and runs host.selection again on what remains (same method, group
    count and sensor limit). The candidate is that family plus the re-selected sensors
    instead of the old ones; it is judged by the same rule as every other candidate. At most
    ``allowed_new`` sensors outside ``baseline_sources`` may come in (host.train's channel
    budget); the least useful newcomers are dropped until it fits.
    """
    pool = [s for s in sensors if s != ambient]
    if not pool:
        return []
    by_source: dict[str, list[Candidate]] = {}
    for c in cands:
        src = input_source(c)
        if src is not None:
            by_source.setdefault(src, []).append(c)
    temps = [make_temp(s) for s in pool]
    fixed = [t for t in current if t.kind != "temp" or t.source == ambient]
    out: list[Candidate] = []
    for src, variants in by_source.items():
        if any(t.source == src and t.kind != "temp" for t in current):
            continue  # this input already has its family in the model
        cand = _reselected_family(variants, cache, y, groups, run_ids, current, temps, fixed,
                                  ambient, period_s, scheme, how, allowed_new, baseline_sources)
        if cand is not None:
            out.append(cand)
    return out


def _reselected_family(variants: Sequence[Candidate], cache: FeatureCache, y: np.ndarray,
                       groups: np.ndarray, run_ids: np.ndarray, current: Sequence[Term],
                       temps: Sequence[Term], fixed: Sequence[Term], ambient: str | None,
                       period_s: float, scheme: str, how: Reselection, allowed_new: int,
                       baseline_sources: set[str]) -> Candidate | None:
    """One input's candidate: its best family variant and the sensors re-selected without
    it; None when the budget refuses it or the selection keeps the model's sensors."""
    fam_terms = list(dict.fromkeys(t for c in variants for t in c.add))
    allcols = list(temps) + [t for t in fixed if t not in temps] + fam_terms
    index = {t: i for i, t in enumerate(allcols)}
    gram = cache.gram(allcols, y, groups)
    every = [index[t] for t in [*temps, *fixed] if t in index]
    best = min(variants, key=lambda c: gram.score(
        list(dict.fromkeys(every + [index[t] for t in c.add])), []).validation_rmse_um)
    Z = np.column_stack([np.ones(y.size), *(cache.column(t) for t in fixed),
                         *(cache.column(t) for t in best.add)])
    YX = np.column_stack([y, cache.matrix(temps)])
    coef, *_ = np.linalg.lstsq(Z, YX, rcond=None)
    R = YX - Z @ coef  # target and temperatures with the family and other effects removed
    result = select_sensors(R[:, 1:], R[:, 0], run_ids, groups, period_s,
                            n_groups=how.n_groups, max_sensors=how.max_sensors,
                            method=how.method, seed=how.seed, scheme=scheme)
    chosen = _within_budget([temps[i] for i in result.sensors], best.add, fixed, gram, index,
                            allowed_new, baseline_sources)
    if chosen is None:
        return None
    add = tuple(best.add) + tuple(t for t in chosen if t not in current)
    remove = tuple(t for t in current if t.kind == "temp" and t.source != ambient
                   and t not in chosen)
    if not remove and add == tuple(best.add):
        return None  # the selection keeps its sensors: the plain family is already a candidate
    return Candidate(best.kind, add, remove, family=tuple(best.add))


def _within_budget(chosen: list[Term], family: Sequence[Term], fixed: Sequence[Term],
                   gram: GramScorer, index: Mapping[Term, int], allowed_new: int,
                   baseline_sources: set[str]) -> list[Term] | None:
    """Drop the newcomers whose loss raises the validation RMSE least until the new sensors
    (outside the baseline's) fit ``allowed_new``; None if the family alone does not fit."""
    chosen = list(chosen)

    def new_sources(ts: Sequence[Term]) -> set[str]:
        return set(term_sensors([*ts, *family, *fixed])) - baseline_sources

    while len(new_sources(chosen)) > allowed_new:
        newcomers = [t for t in chosen if t.source not in baseline_sources]
        if not newcomers:
            return None
        def cost(t: Term) -> float:
            keep = [index[u] for u in [*chosen, *fixed, *family] if u != t]
            return gram.score(list(dict.fromkeys(keep)), []).validation_rmse_um
        chosen.remove(min(newcomers, key=cost))
    return chosen

"""The box's thermocouple budget: all axes together may use at most ``max_channels`` sensors.

When the axes' own choices exceed it, training either drops the cheapest sensors or re-selects
every axis from a shared pool, whichever raises the out-of-fold error least.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping

from contract.terms import TEMPERATURE_KINDS, Term

Selected = dict[str, tuple[list[Term], dict]]  # per axis: terms and selection trace


def channels_of(sel: Mapping[str, list[Term]]) -> set[str]:
    """Thermocouples the terms of all axes need (aux inputs and `time` need none)."""
    return {t.source for terms in sel.values() for t in terms if t.kind in TEMPERATURE_KINDS}


def drop_to_budget(current: Mapping[str, list[Term]], vrmse: Callable[[str, list[Term]], float],
                    max_channels: int) -> tuple[dict[str, list[Term]], list[str]]:
    """Drop the sensor whose removal (with every term built on it, from every axis) raises the
    out-of-fold RMSE least, relative to each axis's current error; repeat until the sensors
    fit ``max_channels``. An axis never loses its last term. Returns the terms and the drops.
    """
    current = {t: list(terms) for t, terms in current.items()}
    score = {t: vrmse(t, terms) for t, terms in current.items()}
    dropped: list[str] = []
    while len(union := channels_of(current)) > max_channels:
        costs: dict[str, tuple[float, dict]] = {}
        for sensor in sorted(union):
            cost, trial = 0.0, {}
            for target, terms in current.items():
                if all(term.source != sensor for term in terms):
                    continue
                rest = [term for term in terms if term.source != sensor]
                if not rest:
                    cost = math.inf
                    break
                trial[target] = (rest, vrmse(target, rest))
                cost += (trial[target][1] - score[target]) / max(score[target], 1e-12)
            costs[sensor] = (cost, trial)
        sensor = min(costs, key=lambda s: costs[s][0])
        for target, (rest, err) in costs[sensor][1].items():
            current[target], score[target] = rest, err
        dropped.append(sensor)
    return current, dropped


def fit_channel_budget(selected: Selected, max_channels: int,
                        vrmse: Callable[[str, list[Term]], float],
                        reselect: Callable[[list[str]], Selected],
                        ) -> tuple[Selected, dict | None]:
    """Make all axes' selected sensors together fit the box's thermocouple channels.

    Returns the per-axis selection that fits and a note for the trace (None when the axes'
    own choices already fit). Two ways are tried and the one whose out-of-fold (validation)
    RMSE rises least, summed over axes relative to each axis's unconstrained error, is kept:
    - ``drop``: drop_to_budget;
    - ``shared-pool``: keep the ``max_channels`` sensors most axes chose (ties: larger |r|)
      and run each axis's selection again on that pool only (lets an axis substitute).
    """
    terms_of = {t: terms for t, (terms, _) in selected.items()}
    union = channels_of(terms_of)
    if len(union) <= max_channels:
        return selected, None
    base = {t: vrmse(t, terms) for t, terms in terms_of.items()}
    current, dropped = drop_to_budget(terms_of, vrmse, max_channels)
    by_drop = {t: (current[t], trace) for t, (_, trace) in selected.items()}

    def rank(name: str) -> tuple[int, float]:
        votes = sum(any(t.source == name for t in terms) for terms, _ in selected.values())
        corr = max(abs(trace["correlations"].get(name, 0.0)) for _, trace in selected.values())
        return votes, corr

    pool = sorted(union, key=rank, reverse=True)[:max_channels]
    by_pool = reselect(pool)

    def cost_of(sel: Selected) -> float:
        return sum(vrmse(t, terms) / max(base[t], 1e-12) - 1.0 for t, (terms, _) in sel.items())

    costs = {"drop": cost_of(by_drop), "shared-pool": cost_of(by_pool)}
    strategy = min(costs, key=costs.get)
    note = {"max_channels": max_channels, "strategy": strategy,
            "dropped": dropped, "pool": pool,
            "relative_validation_cost": {k: round(v, 4) for k, v in costs.items()}}
    chosen = by_drop if strategy == "drop" else by_pool
    if strategy == "shared-pool":  # the pool's traces show only its sensors: keep the rest
        note["outside_pool"] = {
            t: {k: {n: v for n, v in trace[k].items() if n not in pool}
                for k in ("correlations", "delays_s")}
            for t, (_, trace) in selected.items()}
    if len(channels_of({t: terms for t, (terms, _) in chosen.items()})) > max_channels:
        raise AssertionError("channel budget not met")  # both strategies guarantee it
    return chosen, note

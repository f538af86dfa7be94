"""The box's thermocouple budget: all axes together may use at most ``max_channels`` sensors.

When the axes' own choices exceed it, every axis is selected again from a shared pool: the
sensors a multi-task lasso over all axes weighs most. ``drop_to_budget`` is the last resort
after the effects (host.train.pipeline).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping

from thermal_comp.contract.terms import TEMPERATURE_KINDS, Term
from thermal_comp.host.train.training_data import Selections


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


def fit_channel_budget(selected: Selections, max_channels: int,
                        rank: Callable[[list[str]], list[str]],
                        reselect: Callable[[list[str]], Selections],
                        ) -> tuple[Selections, dict | None]:
    """Make all axes' selected sensors together fit the box's thermocouple channels.

    Returns the per-axis selection that fits and a note for the trace (None when the axes'
    own choices already fit). The ``max_channels`` sensors of the axes' selections that
    ``rank`` puts first form a shared pool, and each axis's selection runs again on that pool
    only (an axis may substitute). ``rank`` is a multi-task lasso over all axes at once
    (host.selection.joint_l1_ranking). Before, the budget either dropped the sensors whose
    loss raised least squares' out-of-fold error least, or pooled the sensors most axes
    chose; the pool by the joint lasso was lower on unseen runs of every source
    (docs/training.md).
    """
    terms_of = {t: s.terms for t, s in selected.items()}
    union = channels_of(terms_of)
    if len(union) <= max_channels:
        return selected, None
    pool = rank(sorted(union))[:max_channels]
    chosen = reselect(pool)
    note = {"max_channels": max_channels, "strategy": "shared-pool",
            "ranking": "multi-task lasso over all axes (temperatures and lags, each axis in "
                       "its own unit)",
            "dropped": sorted(union - set(pool)), "pool": pool,
            # the pool's traces show only its sensors: keep the rest
            "outside_pool": {
                t: {k: {n: v for n, v in s.trace[k].items() if n not in pool}
                    for k in ("correlations", "delays_s")}
                for t, s in selected.items()}}
    if len(channels_of({t: s.terms for t, s in chosen.items()})) > max_channels:
        raise AssertionError("channel budget not met")  # the pool guarantees it
    return chosen, note

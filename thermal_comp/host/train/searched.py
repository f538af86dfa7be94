"""Stages 1-2 of ``host train``: every axis's sensors chosen within the box's channel budget,
fitted (eq. 4), and its residual searched for effects, with the budget settled again after them.

Each step reads the one ``TrainingData`` view of the runs (host.train.training_data); the next
day's choice (host.train.next_day_fit) starts from what these return.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

from thermal_comp.contract.terms import Term, term_sensors
from thermal_comp.host.effects import search_effects, sensor_reference
from thermal_comp.host.fitting import NO_REFERENCE, Reference, fit_linear, stack, validation_rmse
from thermal_comp.host.io import Run
from thermal_comp.host.progress import progress
from thermal_comp.host.selection import DEFAULT_BLOCKS, DEFAULT_MAX_SENSORS, joint_l1_ranking
from thermal_comp.host.train.axis_fit import axis_dict
from thermal_comp.host.train.channel_budget import channels_of, drop_to_budget, fit_channel_budget
from thermal_comp.host.train.next_day import channel_fill, lag_taus
from thermal_comp.host.train.training_data import TrainingData

# each axis's selection: its terms and the selection's trace (model.json ``selection``)
Selections = dict[str, tuple[list[Term], dict]]


def fit_axis(runs: list[Run], target: str, terms: list[Term], period_s: float,
             n_blocks: int = DEFAULT_BLOCKS, reference: Reference = NO_REFERENCE) -> dict:
    """Fit ``target`` on fixed terms; the axis dict (unit, intercept, terms, metrics).

    The validation RMSE refits the coefficients without each fold (run, or time block of a
    single run) and predicts it; the terms themselves are taken as given.
    """
    st = stack(runs, terms, target, period_s, n_blocks, reference)
    fit = fit_linear(st.X, st.y)
    oof = validation_rmse(st.X, st.y, st.groups) if st.n_folds >= 2 else math.nan
    return axis_dict(terms, fit.coef, fit.intercept, st.X, st.y, oof, st.scheme)


def axis_with_effects(axis: dict, *, runs: list[Run], target: str, period_s: float,
                      n_blocks: int = DEFAULT_BLOCKS, ambient: str | None = None,
                      max_sensors: int = DEFAULT_MAX_SENSORS,
                      channels_in_use: Sequence[str] = (),
                      reference: Reference = NO_REFERENCE,
                      max_new_sensors: int | None = None) -> dict:
    """The baseline axis dict plus the validated effects (host.effects.search_effects).

    The final terms are fitted once, at the full rate, with the baseline's metrics; the axis
    gains ``effects``, ``unexplained``, ``baseline``, ``effects_search`` and
    ``sensor_reference`` (used by ``host diagnose``).
    """
    baseline = [Term.from_json(t) for t in axis["terms"]]
    found = search_effects(runs, target, baseline, period_s, ambient=ambient, n_blocks=n_blocks,
                           selection=axis.get("selection"), max_sensors=max_sensors,
                           channels_in_use=channels_in_use, reference=reference,
                           max_new_sensors=max_new_sensors)
    out = dict(axis)
    out.update(fit_axis(list(runs), target, found.terms, period_s, n_blocks, reference))
    out.update(found.report)
    out["sensor_reference"] = sensor_reference(runs, term_sensors(found.terms),
                                               axis.get("selection"))
    return out


def selected_within_budget(data: TrainingData, targets: list[str], max_channels: int,
                            choose: dict, quiet: bool) -> Selections:
    """Every axis's selection, then the box's channel budget over all of them."""
    selected = {t: data.select(t, **choose)
                for t in progress(targets, "selecting sensors", quiet=quiet)}
    def rank(sensors: list[str]) -> list[str]:
        return joint_l1_ranking(data.runs, targets, [n for n in data.pool if n in sensors],
                                period_s=data.period_s, taus=lag_taus(data.runs, data.period_s),
                                n_blocks=data.n_blocks, reference=data.ref)

    selected, budget = fit_channel_budget(
        selected, max_channels, rank,
        reselect=lambda pool: {t: data.select(t, pool, **choose) for t in targets})
    for _terms, trace in selected.values():
        if budget:  # the axes together wanted more channels than the box has
            trace["channel_budget"] = budget
    return selected


def free_channel_fill(data: TrainingData, selected: Selections,
                       max_channels: int, rankings: Callable[[], list[list[str]]]
                       ) -> list[str]:
    """The sensors the box's free channels get (the axes' L1 rankings, next_day.channel_fill),
    settled before the effects are searched. An effect that took a free channel changed what
    every axis's ridge reads: axes without an effect of their own got worse on unseen runs
    (docs/training.md). With one axis there is no other axis to harm, and its effects
    (the shop-air family above all) keep the first claim on the free channels."""
    wired = [n for n in data.names if n in channels_of({t: terms for t, (terms, _)
                                                        in selected.items()})]
    return channel_fill(data.runs, list(selected), wired, data.pool, max_channels=max_channels,
                        period_s=data.period_s, n_blocks=data.n_blocks, reference=data.ref,
                        rankings=rankings)


def axes_with_effects(data: TrainingData, selected: Selections, *,
                       effects: bool, ambient: str | None, max_sensors: int,
                       max_channels: int, fill: Sequence[str] = (),
                       quiet: bool) -> dict[str, dict]:
    """Each axis fitted on its selection, then the loop: the effects its residual shows.
    The sensors of ``fill`` are wired already: an effect may use them, not their channels."""
    axes: dict[str, dict] = {}
    for target in progress(list(selected), "fitting axes and effects", quiet=quiet):
        terms, trace = selected[target]
        axis = fit_axis(data.runs, target, terms, data.period_s, data.n_blocks, data.ref)
        axis["selection"] = trace
        baseline_validation = axis["metrics"]["validation_rmse_um"]
        axis["baseline_validation_rmse_um"] = baseline_validation
        axis["effects"] = []
        # The channel budget is settled before the effects are judged: sensors the other axes
        # wire (or will: their selections) cost no channel, and an effect may bring in only as
        # many new sensors as channels are left, so no budget step removes it afterwards.
        others = channels_of({k: [Term.from_json(t) for t in a["terms"]]
                              for k, a in axes.items()})
        others |= channels_of({k: t for k, (t, _) in selected.items() if k not in axes})
        others |= set(fill)
        free = max(0, max_channels - len(others | channels_of({target: terms})))
        if effects:
            axis = axis_with_effects(axis, runs=data.runs, target=target,
                                     period_s=data.period_s, n_blocks=data.n_blocks,
                                     ambient=ambient, max_sensors=max_sensors,
                                     channels_in_use=sorted(others), reference=data.ref,
                                     max_new_sensors=free)
        # on long runs the search scores a thinned-out copy; the baseline figure is full-rate
        axis["baseline_validation_rmse_um"] = baseline_validation
        axes[target] = axis
    return axes


def budget_after_effects(data: TrainingData, axes: dict[str, dict], max_channels: int) -> None:
    """Effects may have brought in sensors (the shop-air sensor, re-selected ones): if all
    axes together now need more channels than the box has, give up the cheapest again."""
    final = {t: [Term.from_json(x) for x in a["terms"]] for t, a in axes.items()}
    if len(channels_of(final)) <= max_channels:
        return
    kept, dropped = drop_to_budget(final, data.vrmse, max_channels)
    for target, axis in axes.items():
        if kept[target] != final[target]:
            gone = {t.name for t in final[target]} - {t.name for t in kept[target]}
            axis.update(fit_axis(data.runs, target, kept[target], data.period_s, data.n_blocks,
                                 data.ref))
            axis["channel_budget_after_effects"] = {
                "max_channels": max_channels, "dropped_sensors": dropped,
                "dropped_terms": sorted(gone)}
            for effect in axis.get("effects", []):
                if any(t.get("source") in dropped for t in effect.get("added", [])):
                    effect["dropped_for_channels"] = True

"""Stages 1-2 of ``host train``: every axis's sensors chosen within the box's channel budget,
fitted (eq. 4), and its residual searched for effects, with the budget settled again after them.

Each step reads the one ``TrainingData`` view of the runs (host.train.training_data) and
returns each axis typed and immutable (``SearchedAxis``), so no later stage edits what an
earlier one decided; the next day's choice (host.train.next_day_fit) starts from them, and
host.train.record turns them into model.json's axes (record.axis_record).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

from thermal_comp.contract.terms import Term, term_sensors
from thermal_comp.host.effects import EffectsReport, search_effects, sensor_reference
from thermal_comp.host.fitting import NO_REFERENCE, Reference, fit_linear, stack, validation_rmse
from thermal_comp.host.io import Run
from thermal_comp.host.progress import progress
from thermal_comp.host.selection import DEFAULT_BLOCKS, DEFAULT_MAX_SENSORS, joint_l1_ranking
from thermal_comp.host.train.axis_fit import AxisFit
from thermal_comp.host.train.channel_budget import channels_of, drop_to_budget, fit_channel_budget
from thermal_comp.host.train.free_channels import channel_fill
from thermal_comp.host.train.ridge_family import lag_taus
from thermal_comp.host.train.training_data import Selections, TrainingData

# an effect's flag: its index in the search's report, the key and the value model.json gives it
EffectFlag = tuple[int, str, Any]


@dataclass(frozen=True)
class SearchedAxis:
    """One axis after the selection, the fit and the effects: its fit on the final terms, the
    selection's trace, the effects search's report (host.effects; empty without the search),
    the channel budget settled again after it, and what later stages said of its effects
    (``effect_flags``, ``effects_rejected``). Immutable: a stage that changes it returns a new
    one (dataclasses.replace), so no stage sees another's edits."""

    fit: AxisFit
    selection: Mapping[str, Any]
    baseline_validation_rmse_um: float
    report: EffectsReport | None = None
    sensor_reference: Mapping[str, Any] | None = None
    budget_after_effects: Mapping[str, Any] | None = None
    effects_rejected: str | None = None
    effect_flags: tuple[EffectFlag, ...] = ()

    @property
    def effects(self) -> list[dict]:
        """The effects the search accepted, each with its flags (in the order they were set)."""
        out = [e.to_json() for e in self.report.effects] if self.report else []
        for i, key, value in self.effect_flags:
            out[i][key] = value
        return out

    @property
    def baseline_terms(self) -> list[Term] | None:
        """The terms before the effects (None without the search)."""
        return list(self.report.baseline_terms) if self.report else None

    def flagged(self, flags: Sequence[EffectFlag]) -> SearchedAxis:
        """This axis with more flags on its effects."""
        return replace(self, effect_flags=(*self.effect_flags, *flags))


def fit_axis(runs: list[Run], target: str, terms: list[Term], period_s: float,
             n_blocks: int = DEFAULT_BLOCKS, reference: Reference = NO_REFERENCE) -> AxisFit:
    """Fit ``target`` on fixed terms: coefficients and metrics.

    The validation RMSE refits the coefficients without each fold (run, or time block of a
    single run) and predicts it; the terms themselves are taken as given.
    """
    st = stack(runs, terms, target, period_s, n_blocks, reference)
    fit = fit_linear(st.X, st.y)
    oof = validation_rmse(st.X, st.y, st.groups) if st.n_folds >= 2 else math.nan
    return AxisFit.of(terms, fit.coef, fit.intercept, st.X, st.y, oof, st.scheme)


def search_axis(runs: list[Run], target: str, baseline: list[Term], selection: Mapping | None,
                *, period_s: float, n_blocks: int = DEFAULT_BLOCKS, ambient: str | None = None,
                max_sensors: int = DEFAULT_MAX_SENSORS, channels_in_use: Sequence[str] = (),
                reference: Reference = NO_REFERENCE, max_new_sensors: int | None = None
                ) -> tuple[AxisFit, EffectsReport, dict]:
    """The validated effects on ``baseline`` (host.effects.search_effects): the final terms
    fitted once, at the full rate; the search's report; the sensors' references (used by
    ``host diagnose``)."""
    found = search_effects(runs, target, baseline, period_s, ambient=ambient, n_blocks=n_blocks,
                           selection=selection, max_sensors=max_sensors,
                           channels_in_use=channels_in_use, reference=reference,
                           max_new_sensors=max_new_sensors)
    fit = fit_axis(list(runs), target, found.terms, period_s, n_blocks, reference)
    return fit, found.report, sensor_reference(runs, term_sensors(found.terms), selection)


def axis_with_effects(axis: dict, *, runs: list[Run], target: str, period_s: float,
                      n_blocks: int = DEFAULT_BLOCKS, ambient: str | None = None,
                      max_sensors: int = DEFAULT_MAX_SENSORS,
                      channels_in_use: Sequence[str] = (),
                      reference: Reference = NO_REFERENCE,
                      max_new_sensors: int | None = None) -> dict:
    """The baseline axis dict plus the validated effects (search_axis), for a caller with an
    axis dict: it gains ``effects``, ``unexplained``, ``baseline``, ``effects_search`` and
    ``sensor_reference``, and the final terms' fit with the baseline's metrics.
    """
    fit, report, references = search_axis(
        runs, target, [Term.from_json(t) for t in axis["terms"]], axis.get("selection"),
        period_s=period_s, n_blocks=n_blocks, ambient=ambient, max_sensors=max_sensors,
        channels_in_use=channels_in_use, reference=reference, max_new_sensors=max_new_sensors)
    return {**axis, **fit.to_json(), **report.to_json(), "sensor_reference": references}


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
    for chosen in selected.values():
        if budget:  # the axes together wanted more channels than the box has
            chosen.trace["channel_budget"] = budget
    return selected


def free_channel_fill(data: TrainingData, selected: Selections,
                       max_channels: int, rankings: Callable[[], list[list[str]]]
                       ) -> list[str]:
    """The sensors the box's free channels get (the axes' L1 rankings, free_channels.channel_fill),
    settled before the effects are searched. An effect that took a free channel changed what
    every axis's ridge reads: axes without an effect of their own got worse on unseen runs
    (docs/training.md). With one axis there is no other axis to harm, and its effects
    (the shop-air family above all) keep the first claim on the free channels."""
    wired = [n for n in data.names if n in channels_of({t: s.terms for t, s
                                                        in selected.items()})]
    return channel_fill(data.runs, list(selected), wired, data.pool, max_channels=max_channels,
                        period_s=data.period_s, n_blocks=data.n_blocks, reference=data.ref,
                        rankings=rankings)


def axes_with_effects(data: TrainingData, selected: Selections, *,
                      effects: bool, ambient: str | None, max_sensors: int,
                      max_channels: int, fill: Sequence[str] = (),
                      quiet: bool) -> dict[str, SearchedAxis]:
    """Each axis fitted on its selection, then the loop: the effects its residual shows.
    The sensors of ``fill`` are wired already: an effect may use them, not their channels."""
    axes: dict[str, SearchedAxis] = {}
    for target in progress(list(selected), "fitting axes and effects", quiet=quiet):
        terms, trace = selected[target]
        fit = fit_axis(data.runs, target, terms, data.period_s, data.n_blocks, data.ref)
        axis = SearchedAxis(fit, trace, fit.metrics["validation_rmse_um"])
        # The channel budget is settled before the effects are judged: sensors the other axes
        # wire (or will: their selections) cost no channel, and an effect may bring in only as
        # many new sensors as channels are left, so no budget step removes it afterwards.
        others = channels_of({k: a.fit.terms for k, a in axes.items()})
        others |= channels_of({k: s.terms for k, s in selected.items() if k not in axes})
        others |= set(fill)
        free = max(0, max_channels - len(others | channels_of({target: terms})))
        if effects:
            found, report, references = search_axis(
                data.runs, target, fit.terms, trace, period_s=data.period_s,
                n_blocks=data.n_blocks, ambient=ambient, max_sensors=max_sensors,
                channels_in_use=sorted(others), reference=data.ref, max_new_sensors=free)
            axis = replace(axis, fit=found, report=report, sensor_reference=references)
        axes[target] = axis
    return axes


def budget_after_effects(data: TrainingData, axes: dict[str, SearchedAxis], max_channels: int
                         ) -> dict[str, SearchedAxis]:
    """Effects may have brought in sensors (the shop-air sensor, re-selected ones): if all
    axes together now need more channels than the box has, give up the cheapest again."""
    final = {t: a.fit.terms for t, a in axes.items()}
    if len(channels_of(final)) <= max_channels:
        return axes
    kept, dropped = drop_to_budget(final, data.vrmse, max_channels)
    out = dict(axes)
    for target, axis in axes.items():
        if kept[target] != final[target]:
            gone = {t.name for t in final[target]} - {t.name for t in kept[target]}
            fit = fit_axis(data.runs, target, kept[target], data.period_s, data.n_blocks,
                           data.ref)
            out[target] = replace(axis, fit=fit, budget_after_effects={
                "max_channels": max_channels, "dropped_sensors": dropped,
                "dropped_terms": sorted(gone)}).flagged(
                [(i, "dropped_for_channels", True) for i, effect in enumerate(axis.effects)
                 if any(t.get("source") in dropped for t in effect.get("added", []))])
    return out

"""Stage 3 of ``host train``: choose the model each axis runs the next day.

The families (host.train.nested.FAMILIES) are judged by nested validation, the chosen one is
fitted on all runs (the ridge over every wired sensor and the free channels, within the box's
filter states), and each axis's choice comes back typed (``NextDayFit``); host.train.record
writes it into model.json (``fit``, the promise in ``metrics``). Its tools each have a room:
the families' nested validation and the promise (host.train.nested), the ridge's basis and
fit (host.train.ridge_family) and the free channels (host.train.free_channels).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

from thermal_comp.contract.terms import Term, term_sensors
from thermal_comp.host.effects.scoring import MIN_GAIN
from thermal_comp.host.fitting import common_period
from thermal_comp.host.io import Run
from thermal_comp.host.progress import progress
from thermal_comp.host.train.channel_budget import channels_of
from thermal_comp.host.train.free_channels import channel_fill
from thermal_comp.host.train.nested import FAMILIES, FoldTerms, NestedResult, nested_validation
from thermal_comp.host.train.options import TrainOptions
from thermal_comp.host.train.ridge_family import (
    EVEN_WARMING_PENALTY,
    RidgeOptions,
    fastest_lag_s,
    lag_family_filters,
    ridge_axis,
    ridge_axis_fit,
    ridge_start,
    shared_lag_budget,
)
from thermal_comp.host.train.searched import EffectFlag, SearchedAxis, fit_axis
from thermal_comp.host.train.summary import dropped_reason
from thermal_comp.host.train.training_data import TrainingData

# a nested fold's training of one axis (host.train.pipeline): runs, target, options -> the axis
TrainFoldAxis = Callable[[list[Run], str, TrainOptions], SearchedAxis]
Rankings = Callable[[], list[list[str]]]


@dataclass(frozen=True)
class NextDayFit:
    """The family an axis runs the next day and why: model.json's ``fit``
    (record.fit_record), with the nested validation that judged it and the promise made from
    it (``promised_family``'s folds; a refill keeps the first judgement's)."""

    family: str
    requested: str  # --fit
    alpha: float | None  # the ridge's penalty (None: least squares)
    free_channels_read: tuple[str, ...]
    even_warming_penalty: float  # only a ridge has the penalty (auto may keep least squares)
    prefilter_tau_s: float  # the ridge's rows low-passed for the fit (host.fitting.prefilter)
    unwired: tuple[str, ...]  # the baseline's sensors the box no longer wires
    nested: NestedResult | None
    promised_family: str
    refilled: bool = False  # the free channels filled again without dropped effects


@dataclass(frozen=True)
class NextDayJob:
    """What every axis's next-day fit shares: the runs' view, the requested family, a nested
    fold's training (``train`` with ``fold_options``) and the ridge's settings."""

    data: TrainingData
    train: TrainFoldAxis
    fold_options: TrainOptions  # TrainOptions.for_fold
    fit: str
    fill_channels: bool
    max_channels: int
    bending: tuple[str, ...]
    prefilter_s: float
    jobs: int | None
    quiet: bool
    rankings: Rankings


@dataclass(frozen=True)
class AxisReading:
    """What one axis's ridge may read: ``fill`` (the free channels), ``pool`` (a nested fold
    fills its own from it), ``box`` (every sensor the box reads) and its ``max_states``
    distinct filters (ridge_family.shared_lag_budget)."""

    max_states: int
    fill: Sequence[str] = ()
    pool: Sequence[str] = ()
    box: Sequence[str] = ()


PROMISE_KEYS = ("promised_rmse_um", "promised_fold_rmse_um", "promised_coverage", "promise")
FAMILY_RULES = {  # what model.json says chose the family, per --fit
    "auto": ("the family with the lowest nested error: least squares on the selected terms "
             "with or without the effects, or a ridge over them plus lags and speed and the "
             "sensors on the free channels"),
    "ridge": ("a ridge over the selected terms plus lags and speed and the sensors on the free "
              "channels (--fit ridge), with the effects only if that ridge is "
              f"{100 * MIN_GAIN:.0f} % lower on its own folds with them (kept unjudged where "
              "they re-selected a sensor the baseline read); least squares where no ridge "
              "keeps the fixed-point bound"),
    "ols": "least squares on the selected terms and the effects (--fit ols)",
}


def fit_for_the_next_day(axis: SearchedAxis, target: str, job: NextDayJob,
                         reading: AxisReading, *, nested: bool
                         ) -> tuple[SearchedAxis, NextDayFit]:
    """Judge the families by nested validation and keep the one for the next day
    (host.train.nested): the axis refitted for it, and the choice.

    The ridge also reads the sensors ``reading.fill`` (free channels); each nested fold fills
    its own from ``reading.pool`` when ``fill`` is not empty (the fold's ranking, not the final
    one). ``reading.box``: the sensors the box reads; a family without the effects is no
    candidate when its terms read another (an effect's re-selection gave that sensor's
    channel away)."""
    final_terms = axis.fit.terms
    baseline_terms = axis.baseline_terms or final_terms
    ridge = RidgeOptions(target in job.bending, job.prefilter_s)
    result = _nested(target, job, reading, ridge) if nested else None
    box = reading.box
    unwired = sorted(set(term_sensors(baseline_terms)) - set(box)) if box else []
    if job.fit == "auto" and result is not None:
        family = min(auto_candidates(final_terms != baseline_terms, unwired), key=result.rms)
    else:
        family = "ridge" if job.fit == "ridge" else "ols"
    with_effects, shrunk = FAMILIES[family]
    data = job.data
    if not with_effects and final_terms != baseline_terms:
        axis = drop_effects(axis, data, target, baseline_terms, "dropped_by_nested_validation",
                            "nested validation: the pipeline refitted without each fold "
                            "predicted it better without the effects")
    alpha, extra = None, []
    if shrunk:
        axis, family, alpha, extra = _ridge_for_the_box(
            axis, target, family, data, reading, ridge, final_terms=final_terms,
            baseline_terms=baseline_terms, with_effects=with_effects, unwired=unwired,
            job_aux=job.fold_options.aux)
    return axis, NextDayFit(
        family=family, requested=job.fit, alpha=alpha, free_channels_read=tuple(extra),
        even_warming_penalty=(EVEN_WARMING_PENALTY
                              if ridge.bending and alpha is not None else 0.0),
        prefilter_tau_s=ridge.prefilter_s if alpha is not None else 0.0,
        unwired=tuple(unwired), nested=result, promised_family=family)


def _nested(target: str, job: NextDayJob, reading: AxisReading, ridge: RidgeOptions
            ) -> NestedResult:
    """The families' nested validation: the pipeline (``job.train``) refitted per fold."""
    data, options = job.data, job.fold_options

    def train_fold(sub: list[Run]) -> FoldTerms:
        axis = job.train(sub, target, options)
        final = axis.fit.terms
        sub_period = common_period(sub)  # a long run's folds are thinned
        extra = channel_fill(sub, [target], term_sensors(final), reading.pool,
                             max_channels=options.max_channels, period_s=sub_period,
                             n_blocks=data.n_blocks, reference=data.ref) if reading.fill else []
        return FoldTerms(final, axis.baseline_terms or final,
                         ridge_start(final, axis.effects, fastest_lag_s(sub, sub_period)), extra)

    return nested_validation(data.runs, target, train_fold, aux=list(options.aux),
                             period_s=data.period_s, n_blocks=data.n_blocks,
                             reference=data.ref, max_states=reading.max_states, ridge=ridge,
                             jobs=job.jobs, quiet=job.quiet)


def _ridge_for_the_box(axis: SearchedAxis, target: str, family: str, data: TrainingData,
                       reading: AxisReading, ridge: RidgeOptions, *, final_terms: list[Term],
                       baseline_terms: list[Term], with_effects: bool, unwired: Sequence[str],
                       job_aux: Sequence[str]
                       ) -> tuple[SearchedAxis, str, float | None, list[str]]:
    """The ridge family fitted on all runs: the axis, the family (``ridge-baseline`` when
    the box's ridge refuses the effects, least squares when no ridge keeps the fixed-point
    bound), its penalty and the free channels it reads."""
    fill, aux = reading.fill, list(job_aux)

    def fit_shrunk(start: Sequence[Term]):
        found = None
        for also in ([fill, ()] if fill else [()]):  # the free channels go first if need be
            found = found or ridge_axis(data.runs, target, start, aux=aux,
                                        period_s=data.period_s, n_blocks=data.n_blocks,
                                        reference=data.ref, max_states=reading.max_states,
                                        also=also, ridge=ridge)
        return found

    terms = (ridge_start(final_terms, axis.effects,
                         fastest_lag_s(data.runs, data.period_s)) if with_effects
             else baseline_terms)
    found = fit_shrunk(terms)
    if found is not None and with_effects and final_terms != baseline_terms and not unwired:
        plain = fit_shrunk(baseline_terms)
        refusal = None if plain is None else ridge_refusal(found[1], plain[1])
        if refusal:  # the box's own model does not gain from the effects: run it without
            family = "ridge-baseline"
            with_effects, terms, found = False, baseline_terms, plain
            axis = drop_effects(axis, data, target, baseline_terms, "dropped_by_box_ridge",
                                refusal)
    if found is None:  # not even the terms alone keep the fixed-point bound: no ridge
        return axis, family.replace("ridge-", "").replace("ridge", "ols"), None, []
    basis, shrunk_fit, st = found
    extra = [s for s in term_sensors(basis) if s not in term_sensors(terms)]
    axis = replace(axis, fit=ridge_axis_fit(basis, shrunk_fit, st))
    if with_effects:
        axis = axis.flagged(lags_in_basis(axis.effects, basis))
    return axis, family, float(shrunk_fit.alpha), extra


def auto_candidates(has_effects: bool, unwired: Sequence[str]) -> list[str]:
    """The families ``--fit auto`` may choose: those with the effects always; those without
    only when there are effects to leave out (else they equal their twin) and the baseline's
    sensors are all still wired (an effect's re-selection may have given a channel away)."""
    return [f for f in FAMILIES if FAMILIES[f][0] or (has_effects and not unwired)]


def ridge_refusal(with_effects, without) -> str | None:
    """Why the box's ridge runs without the accepted effects (None: it keeps them): the ridge
    over the basis with them must be ``MIN_GAIN`` (the search's own 10 %) lower on its
    out-of-fold error than the ridge over the baseline's basis. The search judges an effect on
    least squares over the selected terms; the box runs the ridge over every wired sensor and
    its lags, which often covers what the effect adds, and there an effect that does not gain
    hurt unseen runs (docs/training.md)."""
    a, b = with_effects.validation_rmse_um, without.validation_rmse_um
    if a <= (1 - MIN_GAIN) * b:
        return None
    return (f"its ridge is {a:.3g} um out of fold with them and {b:.3g} um without; they "
            f"must lower it by {100 * MIN_GAIN:.0f} %")


def drop_effects(axis: SearchedAxis, data: TrainingData, target: str,
                 baseline_terms: list[Term], flag: str, why: str) -> SearchedAxis:
    """``axis`` refitted on its baseline terms; its effects stay listed, flagged ``flag``."""
    fit = fit_axis(data.runs, target, baseline_terms, data.period_s, data.n_blocks, data.ref)
    return replace(axis, fit=fit, effects_rejected=why).flagged(
        [(i, flag, True) for i in range(len(axis.effects))])


def lags_in_basis(effects: Sequence[dict], basis: Sequence[Term]) -> list[EffectFlag]:
    """The lag and rate effects whose filter the ridge left to its own lags of the effect's
    sensor (ridge_family.ridge_start), flagged with the lags that stand for it."""
    out: list[EffectFlag] = []
    for i, effect in enumerate(effects):
        if dropped_reason(effect):
            continue  # the box does not run it
        own = lag_family_filters([effect])
        if all(t in basis for t in own):
            continue  # no effect of the lag family, or the box runs its own filter
        sensors = term_sensors(own)
        out.append((i, "in_ridge_lags", [t.name for t in basis
                                         if t.kind == "lag" and t.source in sensors]))
    return out


def mark_lags_in_basis(axis: dict, basis: Sequence[Term]) -> None:
    """lags_in_basis on an axis dict's effects, flagged in place."""
    effects = axis.get("effects", [])
    for i, key, value in lags_in_basis(effects, basis):
        effects[i][key] = value


Judged = dict[str, tuple[SearchedAxis, NextDayFit]]


def for_the_next_day(job: NextDayJob, axes: dict[str, SearchedAxis], *, nested: bool
                     ) -> tuple[dict[str, SearchedAxis], dict[str, NextDayFit]]:
    """The box's model per axis (the next-day families, nested validation), and with the ridge
    the free channels filled again without the effects it dropped: the axes and each axis's
    choice."""
    judged = _axes_for_the_next_day(job, axes, nested)
    if job.fit == "ridge" and job.fill_channels:
        judged = _refilled_without_dropped_effects(job, axes, judged)
    return {t: a for t, (a, _) in judged.items()}, {t: f for t, (_, f) in judged.items()}


def _refilled_without_dropped_effects(job: NextDayJob, searched: dict[str, SearchedAxis],
                                      judged: Judged) -> Judged:
    """The axes judged again when the box's ridge dropped an axis's effects (ridge_refusal)
    that had wired a sensor of their own: the free channels were filled around it, so the box
    would read that sensor for effects it does not run. The channels are filled again with
    those axes on their baseline, and every ridge refitted on them; the nested folds stand
    (each filled its own, whatever the final fill), so they are not run twice."""
    dropped = [t for t, (a, _) in judged.items()
               if any(e.get("dropped_by_box_ridge") for e in a.effects)]
    plain = dict(searched)
    for t in dropped:
        plain[t] = drop_effects(plain[t], job.data, t, plain[t].baseline_terms or [],
                                "dropped_by_box_ridge", judged[t][0].effects_rejected or "")

    def wired(axes: dict[str, SearchedAxis]) -> set[str]:
        return channels_of({t: a.fit.terms for t, a in axes.items()})

    if not dropped or wired(plain) == wired(searched):
        return judged
    out: Judged = {}
    for t, (axis, fit) in _axes_for_the_next_day(job, plain, False).items():
        first = judged[t][1]  # its nested folds and promise stand
        family = ("ridge-baseline" if t in dropped and fit.family == "ridge"  # effects not run
                  else fit.family)
        out[t] = (axis, replace(fit, family=family, refilled=True, nested=first.nested,
                                promised_family=first.promised_family))
    return out


def _axes_for_the_next_day(job: NextDayJob, axes: dict[str, SearchedAxis], nested: bool
                           ) -> Judged:
    """Every axis's family for the next day (fit_for_the_next_day), reading the free
    channels: every axis's ridge reads every wired sensor, and the free channels filled by
    the axes' L1 rankings (a nested fold, trained for one axis, fills its own)."""
    data = job.data
    wired = [n for n in data.names if n in channels_of({t: a.fit.terms for t, a in axes.items()})]
    pool = data.pool
    # with fill_first this is the fill the effects were kept out of (plus any channel an
    # input family's re-selection gave up)
    read = [*wired, *channel_fill(data.runs, list(axes), wired, pool,
                                  max_channels=job.max_channels, period_s=data.period_s,
                                  n_blocks=data.n_blocks, reference=data.ref,
                                  rankings=job.rankings)
            ] if job.fill_channels and job.fit != "ols" else []
    targets = list(axes)
    fastest = fastest_lag_s(data.runs, data.period_s)
    starts = [ridge_start(axes[t].fit.terms, axes[t].effects, fastest) for t in targets]
    budget = shared_lag_budget(starts, read or wired, data.runs, data.period_s)
    return {target: fit_for_the_next_day(axes[target], target, job,
                                         AxisReading(budget[i], read, pool, read or wired),
                                         nested=nested)
            for i, target in enumerate(progress(targets, "nested validation (the next day)",
                                                quiet=job.quiet))}

"""`host train`: select sensors per axis, fit the linear model, validate it, build model.json.

``train_model`` is the library entry point (the CLI, the demo, `host compare` and the tests use
it). Per target axis it runs the selection (host.selection: paper 000's method, ``validated``
or ``paper``), fits eq. 4 on the chosen sensors with host.fitting, reports training and
out-of-fold metrics (host.fitting.validation), searches the effects (closing the loop) and
fits the model for the next day (host.train.next_day). The dict follows docs/model-json.md.
"""

from __future__ import annotations

import copy
import fnmatch
import inspect
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import fields
from functools import cache, wraps
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from thermal_comp.contract.box import CHANNEL_MAX_C, CHANNEL_MIN_C
from thermal_comp.contract.terms import AUX_KINDS, TEMPERATURE_KINDS, Term, term_sensors
from thermal_comp.contract.tilt import Tilt, unit_of
from thermal_comp.host.effects import search_effects, sensor_reference
from thermal_comp.host.effects.scoring import MIN_GAIN
from thermal_comp.host.fitting import (
    NO_REFERENCE,
    Reference,
    common_period,
    fit_linear,
    stack,
    validation_rmse,
)
from thermal_comp.host.fitting.prefilter import PREFILTER_TAU_S
from thermal_comp.host.fitting.step_limits import add_step_limits
from thermal_comp.host.io import Run, load_runs
from thermal_comp.host.io.runs import missing_sensors
from thermal_comp.host.progress import progress
from thermal_comp.host.selection import (
    DEFAULT_BLOCKS,
    DEFAULT_MAX_SENSORS,
    joint_l1_ranking,
)
from thermal_comp.host.service import add_service
from thermal_comp.host.train.axis_fit import axis_dict
from thermal_comp.host.train.channel_budget import channels_of, drop_to_budget, fit_channel_budget
from thermal_comp.host.train.next_day import (
    DEFAULT_RIDGE,
    EVEN_WARMING_PENALTY,
    FAMILIES,
    PROMISE_COVERAGE,
    FoldTerms,
    RidgeOptions,
    channel_fill,
    fastest_lag_s,
    fill_rankings,
    lag_family_filters,
    lag_taus,
    nested_validation,
    promise_statement,
    ridge_axis,
    ridge_axis_dict,
    ridge_start,
    shared_lag_budget,
)
from thermal_comp.host.train.options import TrainOptions
from thermal_comp.host.train.ranges import add_training_ranges
from thermal_comp.host.train.record import model_json
from thermal_comp.host.train.summary import dropped_reason
from thermal_comp.host.train.training_data import TrainingData, TrainingError

# the promise's keys in an axis's metrics (fit_for_the_next_day)
PROMISE_KEYS = ("promised_rmse_um", "promised_fold_rmse_um", "promised_coverage", "promise")
AUX_HEADROOM = 2.0  # valid aux range: twice the training extremes (see _aux)
# BLAS on one thread while training: its matrices have tens of columns, and OpenBLAS's threads
# spin between calls. `host train` on 64 sensors x 86,400 rows used 10.9-14.6 s of CPU with two
# threads and 7.3-9.1 s with one on the 2-core target (the same model; docs/selection.md
# section 7).
# The limit is the process's while train_model runs (threadpoolctl; scikit-learn's KMeans
# limits its BLAS the same way) and is restored when it returns. It covers the BLAS libraries
# loaded when it is set: numpy's, and scipy's own (scikit-learn's lasso calls it).
BLAS_THREADS = 1


def _sensor_columns(temperatures: np.ndarray, idx: list[int]) -> np.ndarray:
    """``temperatures[:, idx]``: a copy, column-major (numpy lays out a gather along the
    second axis so, and every later sum over a run follows that layout). Already
    column-major with every column in order (``host train`` hands its runs so), the array is
    that copy's twin and is used as it is: 44 MB less for 64 sensors x 86,400 rows."""
    if (temperatures.ndim == 2 and temperatures.shape[1] >= 2
            and temperatures.flags.f_contiguous and idx == list(range(temperatures.shape[1]))):
        return temperatures
    return temperatures[:, idx]


def _as_runs(runs: Sequence[Run | str | Path], targets: list[str], sensors: str | list[str],
             aux: list[str], fill_gaps: int, tilts: Sequence[Tilt] = ()) -> list[Run]:
    """Load paths (tilt targets computed from their probes); restrict already-loaded runs to
    the requested sensors."""
    if not runs:
        raise TrainingError("no training runs given")
    if all(isinstance(r, (str, Path)) for r in runs):
        return load_runs(list(runs), targets, sensors, aux, fill_gaps, min_samples=4,
                         tilts=tilts)
    out = []
    for run in runs:
        if not isinstance(run, Run):
            raise TrainingError("runs must be all paths or all host.io.runs.Run objects")
        for t in targets:
            if t not in run.target_names:
                raise TrainingError(f"{run.path}: no target column '{t}'")
        if isinstance(sensors, str):
            names = [n for n in run.sensor_names if fnmatch.fnmatchcase(n, sensors)]
        else:
            names = list(sensors)
        missing = [n for n in names if n not in run.sensor_names]
        if missing:
            raise TrainingError(f"{run.path}: " + missing_sensors(missing, run.sensor_names,
                                                                   "given by sensors"))
        if not names:
            raise TrainingError(f"{run.path}: no sensor column matches {sensors!r}; the run's "
                                f"columns: {', '.join(run.sensor_names)}")
        idx = [run.sensor_names.index(n) for n in names]
        out.append(Run(run.path, run.time_s, names, _sensor_columns(run.temperatures, idx),
                       list(run.target_names), run.displacements, list(run.aux_names), run.aux,
                       run.filled_cells))
    first = out[0].sensor_names
    for run in out[1:]:
        if run.sensor_names != first:
            raise TrainingError(f"{run.path}: sensor columns differ from {out[0].path}")
    return out


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


def fit_for_the_next_day(axis: dict, runs: list[Run], target: str, *, fit: str, nested: bool,
                         options: TrainOptions, period_s: float, n_blocks: int, reference:
                         Reference, max_states: int, fill: Sequence[str] = (), pool:
                         Sequence[str] = (), box: Sequence[str] = (), ridge: RidgeOptions =
                         DEFAULT_RIDGE, jobs: int | None = None, quiet: bool = True) -> dict:
    """Judge the families by nested validation and keep the one for the next day
    (host.train.next_day); the axis gains ``fit`` and the promised error with its spread.

    The ridge also reads the sensors ``fill`` (free channels); each nested fold fills its own
    from ``pool`` when ``fill`` is not empty (the fold's ranking, not the final one). Its basis
    has at most ``max_states`` distinct filters (next_day.shared_lag_budget). ``box``: the
    sensors the box reads; a family without the effects is no candidate when its terms read
    another (an effect's re-selection gave that sensor's channel away). ``ridge``: how the
    ridge is fitted beyond its basis (the bending penalty, the prefilter; next_day)."""
    final_terms = [Term.from_json(x) for x in axis["terms"]]
    baseline = axis.get("baseline")
    baseline_terms = ([Term.from_json(x) for x in baseline["terms"]] if baseline
                      else final_terms)
    aux = list(options.aux)

    def train_fold(sub: list[Run]) -> FoldTerms:
        spec = _train(sub, [target], options)["axes"][target]
        final = [Term.from_json(x) for x in spec["terms"]]
        base = spec.get("baseline")
        sub_period = common_period(sub)  # a long run's folds are thinned
        extra = channel_fill(sub, [target], term_sensors(final), pool,
                             max_channels=options.max_channels, period_s=sub_period,
                             n_blocks=n_blocks, reference=reference) if fill else []
        return FoldTerms(final, [Term.from_json(x) for x in base["terms"]] if base else final,
                         ridge_start(final, spec.get("effects", []),
                                     fastest_lag_s(sub, sub_period)), extra)

    result = None
    if nested:
        result = nested_validation(runs, target, train_fold, aux=aux, period_s=period_s,
                                   n_blocks=n_blocks, reference=reference,
                                   max_states=max_states, ridge=ridge, jobs=jobs,
                                   quiet=quiet)
    unwired = sorted(set(term_sensors(baseline_terms)) - set(box)) if box else []
    if fit == "auto" and result is not None:
        family = min(auto_candidates(final_terms != baseline_terms, unwired), key=result.rms)
    else:
        family = "ridge" if fit == "ridge" else "ols"
    with_effects, shrunk = FAMILIES[family]
    if not with_effects and final_terms != baseline_terms:
        _drop_effects(axis, runs, target, baseline_terms, period_s, n_blocks, reference,
                      "dropped_by_nested_validation",
                      "nested validation: the pipeline refitted without each fold predicted it "
                      "better without the effects")

    def fit_shrunk(start: Sequence[Term]):
        found = None
        for also in ([fill, ()] if fill else [()]):  # the free channels go first if need be
            found = found or ridge_axis(runs, target, start, aux=aux, period_s=period_s,
                                        n_blocks=n_blocks, reference=reference,
                                        max_states=max_states, also=also, ridge=ridge)
        return found

    alpha, extra = None, []
    if shrunk:
        terms = (ridge_start(final_terms, axis.get("effects", []),
                             fastest_lag_s(runs, period_s)) if with_effects
                 else baseline_terms)
        found = fit_shrunk(terms)
        if found is not None and with_effects and final_terms != baseline_terms and not unwired:
            plain = fit_shrunk(baseline_terms)
            refusal = None if plain is None else ridge_refusal(found[1], plain[1])
            if refusal:  # the box's own model does not gain from the effects: run it without
                family = "ridge-baseline"
                with_effects, terms, found = False, baseline_terms, plain
                _drop_effects(axis, runs, target, baseline_terms, period_s, n_blocks,
                              reference, "dropped_by_box_ridge", refusal)
        if found is None:  # not even the terms alone keep the fixed-point bound: no ridge
            family = family.replace("ridge-", "").replace("ridge", "ols")
        else:
            basis, shrunk_fit, st = found
            extra = [s for s in term_sensors(basis) if s not in term_sensors(terms)]
            axis = {**axis, **ridge_axis_dict(basis, shrunk_fit, st)}
            alpha = float(shrunk_fit.alpha)
            if with_effects:
                _mark_lags_in_basis(axis, basis)
    axis["fit"] = {"family": family, "requested": fit, "alpha": alpha,
                   "free_channels_read": extra,
                   # only a ridge has the penalty (auto may keep least squares)
                   "even_warming_penalty": (EVEN_WARMING_PENALTY
                                            if ridge.bending and alpha is not None else 0.0),
                   # the ridge's rows low-passed for the fit (host.fitting.prefilter)
                   "prefilter_tau_s": ridge.prefilter_s if alpha is not None else 0.0,
                   "rule": FAMILY_RULES[fit]}
    if fit == "auto" and unwired:
        axis["fit"]["baseline_not_candidate"] = (
            f"the baseline reads {', '.join(unwired)}, which the box no longer wires (an "
            "effect's re-selection gave the channel away)")
    if result is not None:
        axis["fit"]["nested"] = {"scheme": result.scheme, "fold_rmse_um": result.fold_rmse_um,
                                 "rmse_um": {f: result.rms(f) for f in result.fold_rmse_um}}
        promised = result.promise(family)
        axis["metrics"]["promised_rmse_um"] = promised
        axis["metrics"]["promised_fold_rmse_um"] = result.fold_rmse_um[family]
        # what the figure means (issue 43): its coverage, in the words host train and the
        # report print too
        axis["metrics"]["promised_coverage"] = PROMISE_COVERAGE
        axis["metrics"]["promise"] = (promise_statement(promised, target)
                                      if math.isfinite(promised) else None)
    return axis


def auto_candidates(has_effects: bool, unwired: Sequence[str]) -> list[str]:
    """The families ``--fit auto`` may choose: those with the effects always; those without
    only when there are effects to leave out (else they equal their twin) and the baseline's
    sensors are all still wired (an effect's re-selection may have given a channel away)."""
    return [f for f in FAMILIES if FAMILIES[f][0] or (has_effects and not unwired)]


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


def _drop_effects(axis: dict, runs: list[Run], target: str, baseline_terms: list[Term],
                  period_s: float, n_blocks: int, reference: Reference, flag: str,
                  why: str) -> None:
    """Refit ``axis`` on its baseline terms; its effects stay listed, flagged ``flag``."""
    axis.update(fit_axis(runs, target, baseline_terms, period_s, n_blocks, reference))
    for effect in axis.get("effects", []):
        effect[flag] = True
    axis["effects_rejected"] = why


def _refilled_without_dropped_effects(data: TrainingData, searched: dict[str, dict],
                                      judged: dict[str, dict],
                                      next_day: Callable[[dict[str, dict], bool],
                                                         dict[str, dict]]) -> dict[str, dict]:
    """The axes judged again when the box's ridge dropped an axis's effects (ridge_refusal)
    that had wired a sensor of their own: the free channels were filled around it, so the box
    would read that sensor for effects it does not run. The channels are filled again with
    those axes on their baseline, and every ridge refitted on them; the nested folds stand
    (each filled its own, whatever the final fill), so they are not run twice."""
    dropped = [t for t, a in judged.items()
               if any(e.get("dropped_by_box_ridge") for e in a.get("effects", []))]
    plain = {t: copy.deepcopy(a) for t, a in searched.items()}
    for t in dropped:
        base = [Term.from_json(x) for x in plain[t]["baseline"]["terms"]]
        _drop_effects(plain[t], data.runs, t, base, data.period_s, data.n_blocks, data.ref,
                      "dropped_by_box_ridge", judged[t]["effects_rejected"])

    def wired(axes: dict[str, dict]) -> set[str]:
        return channels_of({t: [Term.from_json(x) for x in a["terms"]] for t, a in axes.items()})

    if not dropped or wired(plain) == wired(searched):
        return judged
    again = next_day(plain, False)
    for t, axis in again.items():
        axis["fit"]["refilled_without_dropped_effects"] = True
        if "nested" in judged[t]["fit"]:
            axis["fit"]["nested"] = judged[t]["fit"]["nested"]
        for key in PROMISE_KEYS:
            if key in judged[t]["metrics"]:
                axis["metrics"][key] = judged[t]["metrics"][key]
        if t in dropped and axis["fit"]["family"] == "ridge":  # its effects are not run
            axis["fit"]["family"] = "ridge-baseline"
    return again


def _mark_lags_in_basis(axis: dict, basis: Sequence[Term]) -> None:
    """Flag the lag and rate effects whose filter the ridge left to its own lags of the
    effect's sensor (next_day.ridge_start), with the lags that stand for it."""
    for effect in axis.get("effects", []):
        if dropped_reason(effect):
            continue  # the box does not run it
        own = lag_family_filters([effect])
        if all(t in basis for t in own):
            continue  # no effect of the lag family, or the box runs its own filter
        sensors = term_sensors(own)
        effect["in_ridge_lags"] = [t.name for t in basis
                                   if t.kind == "lag" and t.source in sensors]


def _channels(axes: Mapping[str, dict], sensor_order: list[str], overrides: Mapping[str, int],
              tc_type: str) -> list[dict]:
    """One channel per sensor any axis uses; defaults 0..k-1 in data-column order."""
    used = {t["source"] for a in axes.values() for t in a["terms"]
            if t["kind"] in TEMPERATURE_KINDS}
    ordered = [s for s in sensor_order if s in used]
    for name, ch in overrides.items():
        if name not in used:
            raise TrainingError(f"--channel {name}={ch}: no axis uses sensor '{name}' "
                                f"(used: {', '.join(ordered) or 'none'})")
        if not isinstance(ch, int) or ch < 0:
            raise TrainingError(f"--channel {name}={ch}: channel must be an integer >= 0")
    taken = list(overrides.values())
    if len(set(taken)) != len(taken):
        raise TrainingError(f"--channel: two sensors on one channel ({dict(overrides)})")
    free = (i for i in range(len(ordered) + len(taken)) if i not in set(taken))
    mapping = {s: overrides[s] if s in overrides else next(free) for s in ordered}
    return [{"channel": mapping[s], "sensor": s, "tc_type": tc_type, "min_c": CHANNEL_MIN_C,
             "max_c": CHANNEL_MAX_C} for s in sorted(ordered, key=lambda s: mapping[s])]


def _aux(axes: Mapping[str, dict], runs: list[Run]) -> list[dict]:
    """Aux inputs any term uses; declared (valid) range = the observed range widened to include
    0, to AUX_HEADROOM times its extremes: a spindle may run faster on an unseen day than in
    training (the box then raises EXTRAP and keeps correcting) without the box calling the
    input faulty and holding (AUX_FAULT)."""
    used = [n for n in runs[0].aux_names
            if any(t["kind"] in AUX_KINDS and t["source"] == n
                   for a in axes.values() for t in a["terms"])]
    out = []
    for i, name in enumerate(used):
        values = np.concatenate([r.column(name) for r in runs])
        lo, hi = float(np.min(values)), float(np.max(values))
        out.append({"input": i, "name": name, "min": math.floor(min(0.0, lo * AUX_HEADROOM)),
                    "max": math.ceil(max(0.0, hi * AUX_HEADROOM))})
    return out


def _one_blas_thread(train: Callable[..., dict]) -> Callable[..., dict]:
    """``train`` with BLAS on ``BLAS_THREADS`` threads while it runs (see BLAS_THREADS)."""
    @wraps(train)
    def limited(*args, **kwargs) -> dict:
        import scipy.linalg  # noqa: F401  (scipy's own OpenBLAS, loaded so the limit covers it)

        with threadpool_limits(limits=BLAS_THREADS, user_api="blas"):
            return train(*args, **kwargs)
    return limited


def _train_signature(train: Callable[..., dict]) -> Callable[..., dict]:
    """``train`` with the signature ``train_model(runs, targets, *, <TrainOptions' fields>)``:
    the options are declared once (host.train.options), and callers that look at the
    keywords (bench.bench_accuracy.train_kwargs) still see each."""
    keywords = [inspect.Parameter(f.name, inspect.Parameter.KEYWORD_ONLY, default=f.default,
                                  annotation=f.type) for f in fields(TrainOptions)]
    train.__signature__ = inspect.signature(train).replace(  # type: ignore[attr-defined]
        parameters=[*list(inspect.signature(train).parameters.values())[:2], *keywords])
    return train


@_train_signature
def train_model(runs: Sequence[Run | str | Path], targets: Sequence[str], **options) -> dict:
    """Select, fit and validate a model for every target; returns the model.json dict.

    ``runs`` are CSV paths or loaded ``Run`` objects; ``options`` are host.train.options.
    TrainOptions' fields. ``selection`` is ``"validated"``
    (representatives and EC subset by out-of-fold error, default) or ``"paper"`` (paper 000
    exactly: by training error). ``channels`` maps sensor -> box channel (others get the
    free indices in data-column order). ``max_delay_s`` limits the delay search.
    ``fill_channels``: the ridge also reads the best-ranked other sensors on the box's free
    channels (host.train.next_day.channel_fill). ``tilts``: targets that are tilt axes (µrad)
    computed from two gap probes of each run (contract/tilt.py); each must be a target.
    ``max_channels`` is the box's thermocouple budget shared by all axes
    (see fit_channel_budget). ``fill_first``: the free channels are filled before the effects
    are searched, which may then only use wired sensors (default: with several axes when the
    ridge reads them, i.e. ``fill_channels`` and a fit other than ``ols``; one axis's effects
    keep the first claim on them; see _free_channel_fill). ``bending``: targets that a
    temperature difference across the structure moves rather than an even warming (a
    column's bending: Y of a vertical machining center); their ridge penalises the response
    to an even warming (host.train.next_day.EVEN_WARMING_PENALTY). ``prefilter_s``: the time
    constant (s) of the low-pass the ridge's rows are fitted through (host.fitting.prefilter;
    0: the raw rows). ``jobs``: at most this many processes train the nested folds (default:
    host.parallel.default_workers; 1: this process); the model does not depend on it.
    """
    return _train(runs, list(targets), TrainOptions.of(**options))


@_one_blas_thread
def _train(runs: Sequence[Run | str | Path], targets: list[str], o: TrainOptions) -> dict:
    """train_model on its options, declared and checked (host.train.options)."""
    o.check(targets)
    fit, nested, max_channels, quiet = o.fit, o.nested, o.max_channels, o.quiet
    data = TrainingData.of(_as_runs(runs, targets, o.sensors, list(o.aux), o.fill_gaps,
                                    o.tilts), targets, o.n_blocks, Reference.of_kind(o.reference))
    choose = dict(groups=o.groups, max_sensors=o.max_sensors, selection=o.selection,
                  max_delay_s=o.max_delay_s, seed=o.seed)
    selected = _selected_within_budget(data, targets, max_channels, choose, quiet)
    data.done_selecting()
    fill_first = o.fill_first
    if fill_first is None:  # the harm it prevents is between axes (_free_channel_fill)
        fill_first = o.fill_channels and fit != "ols" and len(targets) > 1
    # the axes' L1 rankings for the free channels: once, for the fill before the effects and
    # again after them (they do not depend on what is wired)
    rankings = cache(lambda: fill_rankings(data.runs, targets, data.pool,
                                           period_s=data.period_s, n_blocks=data.n_blocks,
                                           reference=data.ref))
    fill = _free_channel_fill(data, selected, max_channels, rankings) if fill_first else []
    axes = _axes_with_effects(data, selected, effects=o.effects, ambient=o.ambient,
                              max_sensors=o.max_sensors, max_channels=max_channels, fill=fill,
                              quiet=quiet)
    _budget_after_effects(data, axes, max_channels)
    if nested or fit == "ridge":
        axes = _for_the_next_day(data, axes, o.for_fold(data.names, fill_first), fit=fit,
                                 nested=nested, fill_channels=o.fill_channels,
                                 max_channels=max_channels, rankings=rankings,
                                 bending=list(o.bending), prefilter_s=o.prefilter_s,
                                 jobs=o.jobs, quiet=quiet)
    used = channels_of({t: [Term.from_json(x) for x in a["terms"]] for t, a in axes.items()})
    if len(used) > max_channels:  # a guarantee of the steps above, checked, never assumed
        raise TrainingError(f"model needs {len(used)} thermocouple channels "
                            f"({', '.join(sorted(used))}), the box has {max_channels}")
    for name, axis in axes.items():  # µm, or µrad for a tilt axis: the name says which
        axis["unit"] = unit_of(name)
    wired = _channels(axes, data.names, dict(o.channels or {}), o.tc_type)
    aux_inputs = _aux(axes, data.runs)
    add_training_ranges(wired, aux_inputs, data.runs)
    sensors = o.sensors
    model = model_json(data, axes, wired, aux_inputs, o.tilts, dict(
        targets=targets, sensors=sensors if isinstance(sensors, str) else list(sensors),
        aux=list(o.aux), selection=o.selection, max_sensors=int(o.max_sensors),
        groups=int(o.groups), max_delay_s=o.max_delay_s, validation=data.scheme,
        seed=int(o.seed), effects=bool(o.effects), reference=data.ref.kind, fit=fit,
        nested=bool(nested), fill_channels=bool(o.fill_channels), ambient=o.ambient,
        max_channels=int(max_channels), bending=list(o.bending),
        prefilter_s=float(o.prefilter_s)))
    # how fast each input and output may change on the box (IMPLAUSIBLE, step limit)
    add_step_limits(model, data.runs)
    # the in-service estimator's parameters from the out-of-fold residual (issue 42)
    add_service(model, data.runs, data.n_blocks, data.ref)
    return model


def _for_the_next_day(data: TrainingData, axes: dict[str, dict], options: TrainOptions, *, fit: str,
                      nested: bool, fill_channels: bool, max_channels: int, rankings,
                      bending: list[str], prefilter_s: float, jobs: int | None,
                      quiet: bool) -> dict[str, dict]:
    """The box's model per axis (the next-day families, nested validation), and with the ridge
    the free channels filled again without the effects it dropped."""
    def next_day(searched: dict[str, dict], nested: bool) -> dict[str, dict]:
        return _axes_for_the_next_day(data, searched, options, fit=fit, nested=nested,
                                      fill_channels=fill_channels,
                                      max_channels=max_channels, rankings=rankings,
                                      bending=bending, prefilter_s=prefilter_s, jobs=jobs,
                                      quiet=quiet)

    refill = fit == "ridge" and fill_channels
    searched = copy.deepcopy(axes) if refill else axes  # the judge updates what it drops
    axes = next_day(axes, nested)
    if refill:
        axes = _refilled_without_dropped_effects(data, searched, axes, next_day)
    return axes


def _selected_within_budget(data: TrainingData, targets: list[str], max_channels: int,
                            choose: dict, quiet: bool) -> dict[str, tuple[list[Term], dict]]:
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


def _free_channel_fill(data: TrainingData, selected: dict[str, tuple[list[Term], dict]],
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


def _axes_with_effects(data: TrainingData, selected: dict[str, tuple[list[Term], dict]], *,
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


def _budget_after_effects(data: TrainingData, axes: dict[str, dict], max_channels: int) -> None:
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


def _axes_for_the_next_day(data: TrainingData, axes: dict[str, dict], options: TrainOptions,
                           *,
                           fit: str, nested: bool, fill_channels: bool, max_channels: int,
                           rankings: Callable[[], list[list[str]]],
                           bending: Sequence[str] = (), prefilter_s: float = PREFILTER_TAU_S,
                           jobs: int | None = None, quiet: bool) -> dict[str, dict]:
    """Every axis's family for the next day (fit_for_the_next_day), reading the free
    channels: every axis's ridge reads every wired sensor, and the free channels filled by
    the axes' L1 rankings (a nested fold, trained for one axis, fills its own)."""
    wired = [n for n in data.names if n in channels_of(
        {t: [Term.from_json(x) for x in a["terms"]] for t, a in axes.items()})]
    pool = data.pool
    # with fill_first this is the fill the effects were kept out of (plus any channel an
    # input family's re-selection gave up)
    read = [*wired, *channel_fill(data.runs, list(axes), wired, pool, max_channels=max_channels,
                                  period_s=data.period_s, n_blocks=data.n_blocks,
                                  reference=data.ref, rankings=rankings)
            ] if fill_channels and fit != "ols" else []
    targets = list(axes)
    fastest = fastest_lag_s(data.runs, data.period_s)
    starts = [ridge_start([Term.from_json(x) for x in axes[t]["terms"]],
                          axes[t].get("effects", []), fastest) for t in targets]
    budget = shared_lag_budget(starts, read or wired, data.runs, data.period_s)
    return {target: fit_for_the_next_day(axes[target], data.runs, target, fit=fit,
                                         nested=nested, options=options,
                                         period_s=data.period_s, n_blocks=data.n_blocks,
                                         reference=data.ref, max_states=budget[i], fill=read,
                                         pool=pool, box=read or wired,
                                         ridge=RidgeOptions(target in bending, prefilter_s),
                                         jobs=jobs, quiet=quiet)
            for i, target in enumerate(progress(targets, "nested validation (the next day)",
                                                quiet=quiet))}



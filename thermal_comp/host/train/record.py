"""The model.json record `host train` writes: the box's inputs and axes, and how it was trained
(docs/model-json.md). The one place the training's typed results (the options, each axis's
next-day choice) become model.json's keys, once, at the end."""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from thermal_comp.contract import __version__
from thermal_comp.contract.box import CHANNEL_MAX_C, CHANNEL_MIN_C
from thermal_comp.contract.model_file import SCHEMA
from thermal_comp.contract.terms import AUX_KINDS, TEMPERATURE_KINDS
from thermal_comp.contract.tilt import unit_of
from thermal_comp.host.io import Run
from thermal_comp.host.train.nested import PROMISE_COVERAGE, promise_statement
from thermal_comp.host.train.next_day_fit import FAMILY_RULES, NextDayFit
from thermal_comp.host.train.options import TrainOptions
from thermal_comp.host.train.ranges import add_training_ranges
from thermal_comp.host.train.searched import SearchedAxis
from thermal_comp.host.train.training_data import TrainingData, TrainingError

TIME_MAX_S = 604800.0  # one week of `time` term before it saturates
AUX_HEADROOM = 2.0  # valid aux range: twice the training extremes (see aux_inputs)


def model_json(data: TrainingData, targets: list[str], options: TrainOptions,
               searched: Mapping[str, SearchedAxis], fits: Mapping[str, NextDayFit]) -> dict:
    """The model.json dict: the box's inputs and axes (each with its next-day ``fit`` and
    promise, from ``fits``), and how it was trained."""
    axes = {name: axis_record(axis) for name, axis in searched.items()}
    for name, axis in axes.items():  # µm, or µrad for a tilt axis: the name says which
        axis["unit"] = unit_of(name)
        if name in fits:
            add_fit(axis, name, fits[name])
    wired = box_channels(axes, data.names, dict(options.channels or {}), options.tc_type)
    aux = aux_inputs(axes, data.runs)
    add_training_ranges(wired, aux, data.runs)
    tilts = options.tilts
    return {
        "schema": SCHEMA,
        "tool_version": __version__,
        "sample_period_s": float(data.period_s),
        "reference": data.ref.to_json(),
        "channels": wired,
        "aux": aux,
        "time_max_s": TIME_MAX_S,
        "axes": axes,
        **({"tilts": [t.to_json() for t in tilts]} if tilts else {}),
        "training": {"runs": [r.path for r in data.runs],
                     **training_record(data, targets, options)},
    }


def axis_record(axis: SearchedAxis) -> dict:
    """An axis of model.json from the stages' typed result (add_fit adds the next day's)."""
    out = axis.fit.to_json()
    out["selection"] = axis.selection
    # full-rate: on long runs the search's report scores a thinned-out copy
    out["baseline_validation_rmse_um"] = axis.baseline_validation_rmse_um
    out["effects"] = axis.effects
    if axis.report:
        out.update({k: v for k, v in axis.report.to_json().items() if k not in out})
        out["sensor_reference"] = axis.sensor_reference
    if axis.budget_after_effects is not None:
        out["channel_budget_after_effects"] = axis.budget_after_effects
    if axis.effects_rejected is not None:
        out["effects_rejected"] = axis.effects_rejected
    return out


def training_record(data: TrainingData, targets: list[str], o: TrainOptions) -> dict:
    """model.json's ``training``: the options the model was trained with."""
    return dict(
        targets=targets, sensors=o.sensors if isinstance(o.sensors, str) else list(o.sensors),
        aux=list(o.aux), selection=o.selection, max_sensors=int(o.max_sensors),
        groups=int(o.groups), max_delay_s=o.max_delay_s, validation=data.scheme,
        seed=int(o.seed), effects=bool(o.effects), reference=data.ref.kind, fit=o.fit,
        nested=bool(o.nested), fill_channels=bool(o.fill_channels), ambient=o.ambient,
        max_channels=int(o.max_channels), bending=list(o.bending),
        prefilter_s=float(o.prefilter_s))


def add_fit(axis: dict, target: str, fit: NextDayFit) -> None:
    """The axis's ``fit`` (its next-day family and why) and, judged by nested validation, the
    promise in its ``metrics``."""
    axis["fit"] = {"family": fit.family, "requested": fit.requested, "alpha": fit.alpha,
                   "free_channels_read": list(fit.free_channels_read),
                   "even_warming_penalty": fit.even_warming_penalty,
                   "prefilter_tau_s": fit.prefilter_tau_s,
                   "rule": FAMILY_RULES[fit.requested]}
    if fit.requested == "auto" and fit.unwired:
        axis["fit"]["baseline_not_candidate"] = (
            f"the baseline reads {', '.join(fit.unwired)}, which the box no longer wires (an "
            "effect's re-selection gave the channel away)")
    if fit.refilled:
        axis["fit"]["refilled_without_dropped_effects"] = True
    result = fit.nested
    if result is None:
        return
    axis["fit"]["nested"] = {"scheme": result.scheme, "fold_rmse_um": result.fold_rmse_um,
                             "rmse_um": {f: result.rms(f) for f in result.fold_rmse_um}}
    promised = result.promise(fit.promised_family)
    metrics = axis["metrics"]
    metrics["promised_rmse_um"] = promised
    metrics["promised_fold_rmse_um"] = result.fold_rmse_um[fit.promised_family]
    # what the figure means (issue 43): its coverage, in the words host train and the
    # report print too
    metrics["promised_coverage"] = PROMISE_COVERAGE
    metrics["promise"] = (promise_statement(promised, target)
                          if math.isfinite(promised) else None)


def box_channels(axes: Mapping[str, dict], sensor_order: list[str], overrides: Mapping[str, int],
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


def aux_inputs(axes: Mapping[str, dict], runs: list[Run]) -> list[dict]:
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

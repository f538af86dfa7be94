"""`host train`: select sensors per axis, fit the linear model, validate it, build model.json.

``train_model`` is the library entry point (the CLI, the demo, `host compare` and the tests use
it). Per target axis it runs the selection (host.selection: paper 000's method, ``validated``
or ``paper``), fits eq. 4 on the chosen sensors with host.fit, reports training and out-of-fold
metrics (host.validation), then hands the baseline to the effects step (issue 7). The model
dict follows docs/model-json.md.
"""

from __future__ import annotations

import fnmatch
import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np

from host import __version__
from host.data import Run, load_runs
from host.extrapolation import add_training_ranges
from host.fit import condition_number, fit_linear, r_squared, rmse, variance_inflation
from host.model_io import AUX_KINDS, SCHEMA, TEMPERATURE_KINDS
from host.progress import progress
from host.selection import (
    DEFAULT_BLOCKS,
    DEFAULT_GROUPS,
    DEFAULT_MAX_SENSORS,
    METHODS,
    select_sensors,
)
from host.terms import Term, make_temp
from host.validation import common_period, fold_groups, stack, validation_rmse

TIME_MAX_S = 604800.0  # one week of `time` term before it saturates
MAX_CHANNELS = 8  # MAX31856 chip selects on the box (firmware BOX_MAX_CHANNELS, PC0..PC7)
DEFAULT_TC_TYPE = "K"
CHANNEL_MIN_C = -40.0
CHANNEL_MAX_C = 200.0


class TrainingError(ValueError):
    """Training inputs are inconsistent (unknown target, bad channel map, ...)."""


def _as_runs(runs: Sequence[Run | str | Path], targets: list[str], sensors: str | list[str],
             aux: list[str], fill_gaps: int) -> list[Run]:
    """Load paths; restrict already-loaded runs to the requested sensors."""
    if not runs:
        raise TrainingError("no training runs given")
    if all(isinstance(r, (str, Path)) for r in runs):
        return load_runs(list(runs), targets, sensors, aux, fill_gaps, min_samples=4)
    out = []
    for run in runs:
        if not isinstance(run, Run):
            raise TrainingError("runs must be all paths or all host.data.Run objects")
        for t in targets:
            if t not in run.target_names:
                raise TrainingError(f"{run.path}: no target column '{t}'")
        if isinstance(sensors, str):
            names = [n for n in run.sensor_names if fnmatch.fnmatchcase(n, sensors)]
        else:
            names = list(sensors)
        missing = [n for n in names if n not in run.sensor_names]
        if missing or not names:
            raise TrainingError(f"{run.path}: sensors {missing or sensors!r} not in the run")
        idx = [run.sensor_names.index(n) for n in names]
        out.append(Run(run.path, run.time_s, names, run.temperatures[:, idx],
                       list(run.target_names), run.displacements, list(run.aux_names), run.aux,
                       run.filled_cells))
    first = out[0].sensor_names
    for run in out[1:]:
        if run.sensor_names != first:
            raise TrainingError(f"{run.path}: sensor columns differ from {out[0].path}")
    return out


def fit_axis(runs: list[Run], target: str, terms: list[Term], period_s: float,
             n_blocks: int = DEFAULT_BLOCKS) -> dict:
    """Fit ``target`` on fixed terms; the axis dict (unit, intercept, terms, metrics).

    The validation RMSE refits the coefficients without each fold (run, or time block of a
    single run) and predicts it; the terms themselves are taken as given.
    """
    st = stack(runs, terms, target, period_s, n_blocks)
    fit = fit_linear(st.X, st.y)
    residual = st.y - fit.predict(st.X)
    vif = variance_inflation(st.X)
    metrics = {
        "train_rmse_um": rmse(residual),
        "validation_rmse_um": validation_rmse(st.X, st.y, st.groups) if st.n_folds >= 2
        else math.nan,
        "raw_rms_um": rmse(st.y),
        "r2": r_squared(st.y, st.y - residual),
        "max_abs_um": float(np.max(np.abs(residual))),
        "condition_number": condition_number(st.X),
        "vif": {t.name: float(v) for t, v in zip(terms, vif, strict=True)},
        "validation": st.scheme,
        "n_samples": int(st.y.size),
    }
    return {
        "unit": "um",
        "intercept": float(fit.intercept),
        "terms": [{**t.to_json(), "coef": float(c)} for t, c in zip(terms, fit.coef, strict=True)],
        "metrics": metrics,
    }


# --- issue 7 hook -------------------------------------------------------------------------
def _add_effects(axis: dict, *, runs: list[Run], target: str, period_s: float, n_blocks: int,
                 enabled: bool, ambient: str | None = None, max_sensors: int,
                 channels_in_use: list[str]) -> dict:
    """EFFECTS HOOK (issue 7, host/effects.py): add validated dynamic/aux effects to the
    fitted baseline axis and return the final axis dict (terms refitted, metrics on the final
    model, plus ``effects``, ``unexplained``, ``baseline``, ``effects_search`` and
    ``sensor_reference`` for ``host diagnose``)."""
    if not enabled:
        return axis
    from host.effects import add_effects

    return add_effects(axis, runs=runs, target=target, period_s=period_s, n_blocks=n_blocks,
                       ambient=ambient, max_sensors=max_sensors,
                       channels_in_use=channels_in_use)


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


Selected = dict[str, tuple[list[Term], dict]]  # per axis: terms and selection trace


def _channels_of(sel: Mapping[str, list[Term]]) -> set[str]:
    """Thermocouples the terms of all axes need (aux inputs and `time` need none)."""
    return {t.source for terms in sel.values() for t in terms if t.kind in TEMPERATURE_KINDS}


def _drop_to_budget(current: Mapping[str, list[Term]], vrmse: Callable[[str, list[Term]], float],
                    max_channels: int) -> tuple[dict[str, list[Term]], list[str]]:
    """Drop the sensor whose removal (with every term built on it, from every axis) raises the
    out-of-fold RMSE least, relative to each axis's current error; repeat until the sensors
    fit ``max_channels``. An axis never loses its last term. Returns the terms and the drops.
    """
    current = {t: list(terms) for t, terms in current.items()}
    score = {t: vrmse(t, terms) for t, terms in current.items()}
    dropped: list[str] = []
    while len(union := _channels_of(current)) > max_channels:
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


def _fit_channel_budget(selected: Selected, max_channels: int,
                        vrmse: Callable[[str, list[Term]], float],
                        reselect: Callable[[list[str]], Selected],
                        ) -> tuple[Selected, dict | None]:
    """Make all axes' selected sensors together fit the box's thermocouple channels.

    Returns the per-axis selection that fits and a note for the trace (None when the axes'
    own choices already fit). Two ways are tried and the one whose out-of-fold (validation)
    RMSE rises least, summed over axes relative to each axis's unconstrained error, is kept:
    - ``drop``: _drop_to_budget;
    - ``shared-pool``: keep the ``max_channels`` sensors most axes chose (ties: larger |r|)
      and run each axis's selection again on that pool only (lets an axis substitute).
    """
    terms_of = {t: terms for t, (terms, _) in selected.items()}
    union = _channels_of(terms_of)
    if len(union) <= max_channels:
        return selected, None
    base = {t: vrmse(t, terms) for t, terms in terms_of.items()}
    current, dropped = _drop_to_budget(terms_of, vrmse, max_channels)
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
    if len(_channels_of({t: terms for t, (terms, _) in chosen.items()})) > max_channels:
        raise AssertionError("channel budget not met")  # both strategies guarantee it
    return chosen, note


def _aux(axes: Mapping[str, dict], runs: list[Run]) -> list[dict]:
    """Aux inputs any term uses; declared range = observed range widened to include 0, +25 %."""
    used = [n for n in runs[0].aux_names
            if any(t["kind"] in AUX_KINDS and t["source"] == n
                   for a in axes.values() for t in a["terms"])]
    out = []
    for i, name in enumerate(used):
        values = np.concatenate([r.column(name) for r in runs])
        lo, hi = float(np.min(values)), float(np.max(values))
        out.append({"input": i, "name": name, "min": math.floor(min(0.0, lo * 1.25)),
                    "max": math.ceil(max(0.0, hi * 1.25))})
    return out


def train_model(runs: Sequence[Run | str | Path], targets: Sequence[str], *,
                sensors: str | list[str] = "T*", aux: Sequence[str] | None = None,
                max_sensors: int = DEFAULT_MAX_SENSORS, groups: int = DEFAULT_GROUPS,
                effects: bool = True, ambient: str | None = None,
                channels: Mapping[str, int] | None = None,
                selection: str = "validated", max_delay_s: float | None = None,
                n_blocks: int = DEFAULT_BLOCKS, seed: int = 0, fill_gaps: int = 0,
                tc_type: str = DEFAULT_TC_TYPE, max_channels: int = MAX_CHANNELS,
                quiet: bool = True) -> dict:
    """Select, fit and validate a model for every target; returns the model.json dict.

    ``runs`` are CSV paths or loaded ``Run`` objects. ``selection`` is ``"validated"``
    (representatives and EC subset by out-of-fold error, default) or ``"paper"`` (paper 000
    exactly: by training error). ``channels`` maps sensor -> box channel (others get the
    free indices in data-column order). ``max_delay_s`` limits the delay search.
    ``max_channels`` is the box's thermocouple budget shared by all axes
    (see _fit_channel_budget).
    """
    targets = list(targets)
    if not targets:
        raise TrainingError("give at least one --target")
    if len(set(targets)) != len(targets):
        raise TrainingError(f"a target is given twice: {targets}")
    if selection not in METHODS:
        raise TrainingError(f"unknown --selection '{selection}' (known: {', '.join(METHODS)})")
    if n_blocks < 2:
        raise TrainingError(f"need at least 2 validation blocks (got {n_blocks})")
    if not 1 <= max_channels <= MAX_CHANNELS:
        raise TrainingError(f"--max-channels must be 1..{MAX_CHANNELS} (the box has "
                            f"{MAX_CHANNELS} thermocouple inputs), got {max_channels}")
    if max_sensors > max_channels:
        raise TrainingError(f"--max-sensors {max_sensors} exceeds --max-channels {max_channels}")
    if tc_type not in ("K", "J"):
        raise TrainingError(f"thermocouple type must be K or J (got {tc_type!r})")
    aux = list(aux or [])
    runs = _as_runs(runs, targets, sensors, aux, fill_gaps)
    period_s = common_period(runs)
    names = runs[0].sensor_names
    n_min = min(r.n_samples for r in runs)
    if len(runs) == 1 and n_min < 2 * n_blocks:
        raise TrainingError(f"{runs[0].path}: {n_min} samples is too few for {n_blocks} "
                            "validation blocks")
    X = np.vstack([r.temperatures for r in runs])
    run_ids = np.concatenate([np.full(r.n_samples, i) for i, r in enumerate(runs)])
    folds, scheme = fold_groups(runs, n_blocks)

    ys = {t: np.concatenate([r.target(t) for r in runs]) for t in targets}

    def select(target: str, pool: list[str] | None = None) -> tuple[list[Term], dict]:
        cols = list(range(len(names))) if pool is None else [names.index(n) for n in pool]
        result = select_sensors(X[:, cols], ys[target], run_ids, folds, period_s,
                                n_groups=groups, max_sensors=max_sensors, method=selection,
                                max_delay_s=max_delay_s, seed=seed, scheme=scheme)
        pool_names = [names[i] for i in cols]
        return [make_temp(pool_names[i]) for i in result.sensors], result.trace(pool_names)

    def vrmse(target: str, terms: list[Term]) -> float:
        st = stack(runs, terms, target, period_s, n_blocks)
        return validation_rmse(st.X, st.y, st.groups)

    selected = {t: select(t) for t in progress(targets, "selecting sensors", quiet=quiet)}
    selected, budget = _fit_channel_budget(
        selected, max_channels, vrmse,
        reselect=lambda pool: {t: select(t, pool) for t in targets})
    for _terms, trace in selected.values():
        if budget:  # the axes together wanted more channels than the box has
            trace["channel_budget"] = budget

    axes: dict[str, dict] = {}
    for target in progress(targets, "fitting axes and effects", quiet=quiet):
        terms, trace = selected[target]
        axis = fit_axis(runs, target, terms, period_s, n_blocks)
        axis["selection"] = trace
        baseline_validation = axis["metrics"]["validation_rmse_um"]
        axis["baseline_validation_rmse_um"] = baseline_validation
        axis["effects"] = []
        # sensors other axes already wire cost no channel; new ones are settled below
        others = _channels_of({k: [Term.from_json(t) for t in a["terms"]]
                               for k, a in axes.items()})
        axis = _add_effects(axis, runs=runs, target=target, period_s=period_s,
                            n_blocks=n_blocks, enabled=effects, ambient=ambient,
                            max_sensors=max_sensors, channels_in_use=sorted(others))
        final_terms = [Term.from_json(t) for t in axis["terms"]]
        if final_terms != terms:  # effects changed the terms: refit, metrics on the final model
            axis.update(fit_axis(runs, target, final_terms, period_s, n_blocks))
        # on long runs the search scores a thinned-out copy; the baseline figure is full-rate
        axis["baseline_validation_rmse_um"] = baseline_validation
        axes[target] = axis

    # Effects may have brought in sensors (the shop-air sensor, re-selected ones): if all axes
    # together now need more channels than the box has, give up the cheapest sensors again.
    final = {t: [Term.from_json(x) for x in a["terms"]] for t, a in axes.items()}
    if len(_channels_of(final)) > max_channels:
        kept, dropped = _drop_to_budget(final, vrmse, max_channels)
        for target, axis in axes.items():
            if kept[target] != final[target]:
                gone = {t.name for t in final[target]} - {t.name for t in kept[target]}
                axis.update(fit_axis(runs, target, kept[target], period_s, n_blocks))
                axis["channel_budget_after_effects"] = {
                    "max_channels": max_channels, "dropped_sensors": dropped,
                    "dropped_terms": sorted(gone)}
                for effect in axis.get("effects", []):
                    if any(t.get("source") in dropped for t in effect.get("added", [])):
                        effect["dropped_for_channels"] = True
    used = _channels_of({t: [Term.from_json(x) for x in a["terms"]] for t, a in axes.items()})
    if len(used) > max_channels:  # a guarantee of the steps above, checked, never assumed
        raise TrainingError(f"model needs {len(used)} thermocouple channels "
                            f"({', '.join(sorted(used))}), the box has {max_channels}")

    wired = _channels(axes, names, dict(channels or {}), tc_type)
    aux_inputs = _aux(axes, runs)
    add_training_ranges(wired, aux_inputs, runs)
    return {
        "schema": SCHEMA,
        "tool_version": __version__,
        "sample_period_s": float(period_s),
        "channels": wired,
        "aux": aux_inputs,
        "time_max_s": TIME_MAX_S,
        "axes": axes,
        "training": {
            "runs": [r.path for r in runs],
            "targets": targets,
            "sensors": sensors if isinstance(sensors, str) else list(sensors),
            "aux": aux,
            "selection": selection,
            "max_sensors": int(max_sensors),
            "groups": int(groups),
            "max_delay_s": max_delay_s,
            "validation": scheme,
            "seed": int(seed),
            "effects": bool(effects),
            "ambient": ambient,
            "max_channels": int(max_channels),
        },
    }


def axis_sensors(axis: dict) -> list[str]:
    """Temperature sources of an axis's terms, in term order, each once."""
    out: list[str] = []
    for t in axis["terms"]:
        if t["kind"] in TEMPERATURE_KINDS and t["source"] not in out:
            out.append(t["source"])
    return out


def summary(model: dict, model_path: str) -> dict:
    """The ``host train --json`` document (issue 2's fixed shape plus a few extras)."""
    axes = {}
    for name, axis in model["axes"].items():
        m = axis["metrics"]
        axes[name] = {
            "sensors": axis_sensors(axis),
            "train_rmse_um": m["train_rmse_um"],
            "validation_rmse_um": m["validation_rmse_um"],
            "raw_rms_um": m["raw_rms_um"],
            "r2": m.get("r2"),
            "max_abs_um": m.get("max_abs_um"),
            "condition_number": m.get("condition_number"),
            "validation": m.get("validation"),
            # issue 7: before/after the effects, what was added and what is still unexplained
            "baseline_validation_rmse_um": axis.get("baseline_validation_rmse_um"),
            "effects": [{k: e.get(k) for k in ("kind", "feature", "evidence", "rmse_before_um",
                                               "rmse_after_um")}
                        for e in axis.get("effects", [])],
            "unexplained": axis.get("unexplained"),
        }
    return {"model": model_path, "axes": axes}

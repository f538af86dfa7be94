"""`host report`'s selection and effects story: paper 000's groups and count rule, the
selection figure, the folds' stages, the effects' evidence and stages, the correlated peers."""

from __future__ import annotations

import html
import math
from pathlib import Path

import numpy as np

from thermal_comp.contract.tilt import available_axes, model_tilts, unit_text
from thermal_comp.host.analysis import plots
from thermal_comp.host.analysis.compare import DEFAULT_K_CORRELATED, most_correlated
from thermal_comp.host.analysis.report_data import box_sensors, dropped_sensors, predict, run_header
from thermal_comp.host.fitting import NO_REFERENCE, Reference, fit_linear
from thermal_comp.host.io import Run, load_run
from thermal_comp.host.selection import default_max_lag
from thermal_comp.host.train import (
    box_model_note,
    dropped_reason,
    ridge_lags_note,
)


def count_rule(sel: dict, model: dict) -> str:
    """Which rule fixed the selection's sensor count: "ec" (smallest EC_i, paper 000), "min"
    (smallest out-of-fold error S_i) or "cap" (the smallest S_i lies beyond --max-sensors, so
    the cap decided)."""
    if sel.get("count_rule", "smallest EC_i") == "smallest EC_i":
        return "ec"
    errors = [float(e) for e in sel.get("ec_errors_um") or []]
    chosen = int(sel.get("chosen_count", 0))
    cap = int(model.get("training", {}).get("max_sensors") or 0)
    if errors and cap and chosen == cap and int(np.argmin(errors)) + 1 > cap:
        return "cap"
    return "min"


def delay_limit_s(model: dict) -> float | None:
    """The limit of the delay search training used (s): ``--max-delay-h`` when given, else a
    quarter of the shortest training run (host.selection's default), read from the runs;
    None when the runs are not readable here."""
    training = model.get("training", {})
    period = float(model["sample_period_s"])
    if training.get("max_delay_s") is not None:
        return float(training["max_delay_s"])
    lengths = []
    for p in training.get("runs", []):
        path = Path(p)
        if not path.is_file():
            return None
        with path.open(encoding="utf-8-sig") as fh:
            lengths.append(sum(1 for line in fh if line.strip()) - 1)
    if not lengths:
        return None
    n = min(lengths)
    return min(default_max_lag(n), n - 1) * period


def selection_groups(axis: dict) -> list[dict]:
    """Paper 000's Table 1 for this axis: each c-means group, its members, its centre
    (mean delay and correlation of the members) and which member the box reads."""
    sel = axis["selection"]
    box = set(box_sensors(axis))
    rows = []
    for g, members in enumerate(sel.get("groups") or []):
        if not members:
            continue
        delays = [float(sel.get("delays_s", {}).get(m, math.nan)) for m in members]
        corr = [float(sel.get("correlations", {}).get(m, math.nan)) for m in members]
        rows.append({"group": g, "members": list(members),
                     "centre_delay_s": float(np.mean(delays)),
                     "centre_r": float(np.mean(corr)),
                     "chosen": [m for m in members if m in sel.get("sensors", [])],
                     "read_by_box": [m for m in members if m in box]})
    return rows


def one_per_group(axis: dict) -> bool:
    """Whether c-means left every candidate sensor in a group of its own."""
    groups = [g for g in (axis.get("selection") or {}).get("groups") or [] if g]
    return len(groups) > 1 and all(len(g) == 1 for g in groups)


def effect_sensors(axis: dict) -> set[str]:
    """Sensors whose terms the effects the box runs added."""
    return {str(t["source"]) for eff in axis.get("effects") or [] if not dropped_reason(eff)
            for t in eff.get("added") or [] if t.get("source")}


def _grouping_note(axis_name: str, axis: dict, requested: int | None = None) -> str:
    """Why every sensor is a group of its own, when it is (paper 000's grouping did nothing):
    c-means is capped at the number of candidates, and ``--groups`` (default 10) was not
    below it; the channel budget's shared pool is often what set that number."""
    if not one_per_group(axis):
        return ""
    sel = axis["selection"]
    n = sum(1 for g in sel.get("groups") or [] if g)
    pool = (sel.get("channel_budget") or {}).get("pool")
    outside = ((sel.get("channel_budget") or {}).get("outside_pool") or {}).get(axis_name, {})
    n_out = len(outside.get("correlations") or {})
    text = (f" Each of the {n} candidate sensors is a group of its own: c-means makes at most "
            "as many groups as there are candidates, and "
            + (f"--groups {requested}" if requested is not None else "--groups (default 10)")
            + f" is not below {n}")
    if pool and n_out:
        text += (f" (the {n} are the channel budget's shared pool: {n_out} more sensors had "
                 "no box channel left)")
    return (text + ". So the grouping of paper 000 narrowed nothing here: every candidate was "
            "tried as its own representative, and sensors that sit together in the plane "
            f"were judged one by one. Train with --groups below {n} to group them.")


def selection_figure(axis_name: str, axis: dict, limit_s: float | None = None,
                      groups_requested: int | None = None):
    sel = axis["selection"]
    names = list(sel.get("correlations", {}))
    delays = [float(sel.get("delays_s", {}).get(n, math.nan)) for n in names]
    corr = [float(sel["correlations"][n]) for n in names]
    labels = [int(sel.get("labels", {}).get(n, 0)) for n in names]
    box = box_sensors(axis)
    selected = list(sel.get("sensors", []))
    dropped = [n for n in selected if n not in box]
    # sensors the box's channel budget left out of the shared pool: drawn as group -1
    outside = sel.get("channel_budget", {}).get("outside_pool", {}).get(axis_name, {})
    for n, r in outside.get("correlations", {}).items():
        names.append(n)
        corr.append(float(r))
        delays.append(float(outside.get("delays_s", {}).get(n, math.nan)))
        labels.append(-1)
    shown = [n for n in box if n in names]
    fig = plots.selection_plane(axis_name, names, delays, corr, labels, shown, dropped,
                                limit_s)
    e = html.escape
    title = f"{axis_name}: sensors by delay and correlation"
    caption = (f"Each dot is a thermocouple: how strongly it correlates with {axis_name} and how "
               "far it lags behind it. "
               + ("" if one_per_group(axis) else
                  "Colours are the c-means groups (◇: each group's centre; the table below "
                  "lists the members); one representative per group is tried. ")
               + f"Circled and named: the sensors the box reads for {axis_name} "
               f"({e(', '.join(box)) or 'none'}).")
    caption += _dropped_caption(axis, dropped)
    caption += _added_caption(axis, [n for n in box if n not in selected])
    caption += _grouping_note(axis_name, axis, groups_requested)
    if limit_s:
        at_edge = [n for n, d in zip(names, delays, strict=True)
                   if math.isfinite(d) and abs(d) >= limit_s - 1e-6]
        caption += (f" Triangles: delay at the limit of the search (±{limit_s / 3600:.3g} h): "
                    + (e(", ".join(at_edge)) if at_edge else "none")
                    + (", whose true delay may be longer." if at_edge else "."))
    caption += f" Method: {e(str(sel.get('method', '?')))}."
    return fig, title, caption


def _dropped_caption(axis: dict, dropped: list[str]) -> str:
    """The caption's word on the dashed circles: chosen by the selection, then dropped by the
    box's channel budget, or otherwise missing from the box's model."""
    e = html.escape
    sel = axis["selection"]
    caption = ""
    budget = set(dropped_sensors(axis)) | set((sel.get("channel_budget") or {}).get("dropped")
                                              or [])
    by_budget = [n for n in dropped if n in budget]
    other = [n for n in dropped if n not in budget]
    if by_budget:
        caption += (f" Dashed: chosen by the selection but dropped by the box's channel "
                    f"budget ({e(', '.join(by_budget))}); the box does not read "
                    f"{'it' if len(by_budget) == 1 else 'them'} for this axis.")
    if other:
        caption += (f" Dashed: chosen by the selection but not in the box's model "
                    f"({e(', '.join(other))}).")
    return caption


def _added_caption(axis: dict, added: list[str]) -> str:
    """The caption's word on sensors the box reads that the selection did not choose: on
    channels it left free, brought in by an effect, or neither."""
    e = html.escape
    caption = ""
    free = [n for n in added if n in set((axis.get("fit") or {}).get("free_channels_read")
                                         or [])]
    by_effects = [n for n in added if n not in free and n in effect_sensors(axis)]
    other = [n for n in added if n not in free and n not in by_effects]
    if free:
        caption += (" Read by the box's ridge on channels the selection left free, not chosen "
                    "by the selection (fit.free_channels_read: the best of the other sensors "
                    f"by an L1 ranking over all axes): {e(', '.join(free))}.")
    if by_effects:
        caption += (f" Brought in by the effects rather than the selection: "
                    f"{e(', '.join(by_effects))}.")
    if other:
        caption += (f" Read by the box's model though neither selected nor brought in by an "
                    f"effect it runs: {e(', '.join(other))}.")
    return caption


def fold_stages(axis: dict) -> list[dict]:
    """Validation RMSE of each stage with its per-fold values, from the effects' evidence:
    the baseline (the first effect's folds before) and after each effect; [] when the model
    does not carry them."""
    effects = axis.get("effects") or []
    first = (effects[0].get("evidence") or {}) if effects else {}
    if not effects or not first.get("fold_rmse_before_um"):
        return []
    rows = [{"stage": "baseline", "rmse_um": effects[0].get("rmse_before_um"),
             "folds_um": list(first["fold_rmse_before_um"]), "dropped": False}]
    for e in effects:
        ev = e.get("evidence") or {}
        if not ev.get("fold_rmse_after_um") or e.get("rmse_after_um") is None:
            return []
        rows.append({"stage": "+ " + str(e.get("name", e.get("kind", "?"))),
                     "rmse_um": e["rmse_after_um"], "folds_um": list(ev["fold_rmse_after_um"]),
                     "dropped": dropped_reason(e) is not None, "why": dropped_reason(e)})
    if any(r["rmse_um"] is None for r in rows):
        return []
    return rows


def effect_evidence(effect: dict, unit: str = "µm") -> str:
    """The numbers that justified an effect, in one phrase (errors in ``unit``)."""
    parts = []
    before, after = effect.get("rmse_before_um"), effect.get("rmse_after_um")
    if before is not None and after is not None:
        parts.append(f"validation RMSE {before:.2f} → {after:.2f} {unit}")
    ev = effect.get("evidence") or {}
    if ev.get("improvement_pct") is not None:
        parts.append(f"{ev['improvement_pct']:.0f} % better")
    if ev.get("folds_improved"):
        parts.append(f"better in {ev['folds_improved']} folds")
    if ev.get("residual_corr") is not None:
        parts.append(f"residual correlation {ev['residual_corr']:+.2f}")
    return ", ".join(parts)


def effects_caption(stages: list[dict]) -> str:
    """What the effects figure's caption says of its stages (HTML): why each effect the box
    runs was added, and each one it does not run with the reason from its flags
    (dropped_reason: the channel budget, nested validation, the box's ridge), grouped by it."""
    e = html.escape
    kept = [s for s in stages if not s["dropped"] and s.get("name") is not None]
    gone = [s for s in stages if s["dropped"]]
    parts = []
    if kept:
        parts.append("Why each effect in the box's model was added: " + "; ".join(
            f"<b>{e(s['name'])}</b>: {e(s['evidence']) or 'no evidence recorded'}"
            + (f" ({e(s['note'])})" if s.get("note") else "") for s in kept) + ".")
    else:
        parts.append("The box's model runs none of the effects the search added.")
    reasons: dict[str, list[dict]] = {}
    for s in gone:
        reasons.setdefault(str(s["why"]), []).append(s)
    for why, group in reasons.items():
        parts.append("Dashed grey, added by the search on this evidence but dropped because "
                     + e(why) + ": " + "; ".join(
                         f"<b>{e(s['name'])}</b> ({e(s['evidence']) or 'no evidence recorded'})"
                         for s in group) + ".")
    box = next((s for s in stages if s["box"]), None)
    if gone and box is not None:
        parts.append("The last curve is what the box runs"
                     + (f": {e(box['note'])}." if box.get("note") else "."))
    return " ".join(parts)


def effect_stages(axis: dict, axis_name: str, run: Run, period: float,
                  reference: Reference = NO_REFERENCE) -> list[dict]:
    """Residual of the baseline model and after each effect, in the order they were added,
    then (when the channel budget changed it afterwards) the model the box runs.

    Each effect records the model it produced (``intercept`` and ``terms``) and the axis keeps
    the ``baseline`` it started from (host/effects/), so every stage is re-evaluated here on
    this run, seen or unseen. An effect the channel budget took out is kept as a stage marked
    ``dropped`` (what it would have done), and the last stage is always the box's model, so the
    figure's final error is the box's.
    """
    measured = run.target(axis_name)
    stages = []
    baseline = axis.get("baseline")
    if baseline and "terms" in baseline:
        stages.append({"label": "baseline (temperatures only)",
                       "legend": "baseline (temperatures only)", "evidence": "",
                       "dropped": False, "box": False,
                       "residual": measured - predict(baseline["intercept"], baseline["terms"],
                                                      run, period, reference)})
    for effect in axis.get("effects", []):
        if "terms" in effect and "intercept" in effect:
            why = dropped_reason(effect)
            dropped = why is not None
            name = effect.get("name", effect.get("kind", "?"))
            stages.append({"label": f"+ {name}" + (f" (dropped: {why})" if dropped else ""),
                           "legend": f"+ {name}" + (" (dropped)" if dropped else ""),
                           "name": name, "evidence": effect_evidence(effect, unit_text(axis_name)),
                           "why": why, "note": ridge_lags_note(effect),
                           "dropped": dropped, "box": False,
                           "residual": measured - predict(effect["intercept"], effect["terms"],
                                                          run, period, reference)})
    note = box_model_note(axis)
    if stages and note:
        stages.append({"label": f"the box's model ({note})", "legend": "the box's model",
                       "note": note, "evidence": "", "dropped": False, "box": True,
                       "residual": measured - predict(axis["intercept"], axis["terms"], run,
                                                      period, reference)})
    elif stages:
        stages[-1]["box"] = True
    return stages


def peer_predictions(model: dict, runs: list[Run]) -> dict[str, dict[tuple[str, str], np.ndarray]]:
    """Predictions of the static peers `host compare` also fits (OLS on all sensors, OLS on the
    k most correlated), trained on the model's own training runs so the comparison is fair.

    Empty when the training runs are not readable here (the report then shows our model only).
    """
    training = model.get("training", {})
    ref = Reference.of_model(model)
    paths = [Path(p) for p in training.get("runs", [])]
    axes = [a for a in model["axes"] if any(a in r.target_names for r in runs)]
    if not paths or not all(p.is_file() for p in paths) or not axes:
        return {}
    try:
        tilts = model_tilts(model)
        train_runs = [load_run(p, available_axes(run_header(p), axes, tilts),
                               training.get("sensors", "T*"), tilts=tilts) for p in paths]
    except ValueError:
        return {}
    names = train_runs[0].sensor_names
    if any(r.sensor_names != names for r in train_runs) or \
            not all(set(names) <= set(r.sensor_names) for r in runs):
        return {}
    k = min(DEFAULT_K_CORRELATED, len(names))
    labels = ("OLS, all sensors", f"{k} most correlated (paper 002)")
    out: dict[str, dict[tuple[str, str], np.ndarray]] = {label: {} for label in labels}
    for axis in axes:
        have = [r for r in train_runs if axis in r.target_names]
        if not have:
            continue
        X = np.vstack([ref.apply(r.temperatures) for r in have])
        y = np.concatenate([ref.apply(r.target(axis)) for r in have])
        top = most_correlated(X, y, k)
        for label, idx in zip(labels, (np.arange(len(names)), top), strict=True):
            fit = fit_linear(X[:, idx], y)
            cols = [names[i] for i in idx]
            for run in runs:
                if axis in run.target_names:
                    Xr = np.column_stack([run.column(c) for c in cols])
                    out[label][(run.path, axis)] = ref.apply(fit.predict(Xr))
    return out

"""`host report`: one self-contained HTML page (plus the PNGs) that tells the model's story.

Why a static page: it opens anywhere without a server or network (images are embedded as data
URIs, the same PNGs are written beside it for slides), and it is reproducible from the model
file and the runs alone. The figures follow paper 000 (sensor plane, EC curve) and add what the
papers do not show: unseen runs, peers, the effects added to close the loop, the heating and
cooling paths and the fixed-point error bound. Figures are drawn in ``host.analysis.plots``.
"""

from __future__ import annotations

import csv
import html
import io
import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from thermal_comp.contract.model_file import (
    ModelSpec,
    model_hash,
    read_model,
    spec_of,
    write_text_atomic,
)
from thermal_comp.contract.tilt import unit_text
from thermal_comp.host.analysis import plots
from thermal_comp.host.analysis.evaluate import model_reference
from thermal_comp.host.analysis.metrology import (
    coefficient_table,
    iso230_drift,
    wiring_rows,
)
from thermal_comp.host.analysis.report_data import (
    Figure,
    ProtocolMatrix,
    Report,
    box_sensors,
    dropped_sensors,
    effect_label,
    in_training,
    load_hil,
    load_locations,
    load_protocols,
    load_report_runs,
    most_important_sensor,
    predict,
    referenced,
    training_runs,
)
from thermal_comp.host.analysis.report_html import render_html
from thermal_comp.host.analysis.report_story import (
    count_rule,
    delay_limit_s,
    effect_stages,
    effects_caption,
    fold_stages,
    peer_predictions,
    selection_figure,
    selection_groups,
)
from thermal_comp.host.analysis.service import readings_for, service_day
from thermal_comp.host.fitting import Reference, axis_terms, linear_prediction
from thermal_comp.host.io import CsvFormat, Run
from thermal_comp.host.progress import progress
from thermal_comp.host.service import ProbePlan
from thermal_comp.host.train import (
    TOLERANCE_SHARE,
    box_effects_evidence,
    dropped_reason,
    input_units,
    outside_training,
    training_ranges,
)

# ---------------------------------------------------------------- report

def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text).strip("_") or "x"


def _save(fig, path: Path) -> list[str]:
    """Write the PNG; what of it is cut off at the image's edge (plots.clipped_artists)."""
    return plots.save_png(fig, path)


def summary_rows(model: dict) -> list[dict]:
    """Row per axis: what the box stores and how well it did in validation (item 7)."""
    fixed = (model.get("fixed_point") or {}).get("axes", {})
    rows = []
    for name, axis in model["axes"].items():
        metrics = axis.get("metrics", {})
        sensors = sorted({t["source"] for t in axis["terms"]
                          if t.get("source") in {c["sensor"] for c in model["channels"]}})
        channels = sorted(c["channel"] for c in model["channels"] if c["sensor"] in sensors)
        val = metrics.get("validation_rmse_um")
        raw = metrics.get("raw_rms_um")
        reduction = (1.0 - val / raw) * 100.0 if val is not None and raw else None
        rows.append({
            "axis": name, "sensors": sensors, "channels": channels,
            "coefficients": len(axis["terms"]) + 1,
            "error_bound_um": (fixed.get(name) or {}).get("bound_um"),
            "input_quantisation_um": (fixed.get(name) or {}).get("input_quantisation_um"),
            "validation_rmse_um": val, "raw_rms_um": raw, "reduction_pct": reduction,
            "baseline_validation_rmse_um": axis.get("baseline_validation_rmse_um"),
            # the effect search's own figure after its effects (least squares, its folds)
            "effects_validation_rmse_um": axis.get("validation_rmse_um"),
            # the box's family on the nested folds, without and with its effects
            "box_nested_rmse_um": box_effects_evidence(axis),
            "fit": fit_label(axis.get("fit") or {}),
            "effects": [e.get("name", "?") for e in axis.get("effects", [])
                        if not dropped_reason(e)],
            "effects_dropped": [e.get("name", "?") for e in axis.get("effects", [])
                                if dropped_reason(e)],
            # every effect as the page shows it: dropped, or modelled by the ridge's lags
            "effect_labels": [effect_label(e) for e in axis.get("effects", [])],
            "sensors_dropped": dropped_sensors(axis),
            "validation": metrics.get("validation"),
        })
    return rows


def fit_label(fit: dict) -> str | None:
    """The fit family, and for a ``--bending`` axis that its even warming was penalised."""
    family = fit.get("family")
    if family and fit.get("even_warming_penalty"):
        return f"{family}, bending"
    return family


@dataclass
class _Inputs:
    """What every figure of one report reads: the model, the referenced runs, and the
    per-run error table the figures fill in for the summary."""

    model: dict
    spec: ModelSpec  # the model's function, typed (the dict holds its report fields)
    runs: list[Run]
    ref: Reference
    period: float
    peer_models: dict
    matrix: ProtocolMatrix | None
    ranges: dict | None
    limit: float | None
    run_table: dict[str, dict] = field(default_factory=dict)
    # run path -> axis -> host.analysis.service.service_day (runs with probe readings)
    service: dict[str, dict[str, dict]] = field(default_factory=dict)
    service_source: dict[str, str] = field(default_factory=dict)  # run path -> readings

    def prediction(self, axis: str, run: Run) -> np.ndarray:
        """The model's float prediction of ``axis`` on ``run``, referenced as the box's."""
        terms, coefs, intercept = axis_terms(self.spec, axis)
        return self.ref.apply(linear_prediction(terms, coefs, intercept, run.columns(),
                                                self.period, run.n_samples))


# A figure: (matplotlib figure, title, caption HTML, file name), or None when it has nothing
# to show for this axis and run.
Drawn = tuple[object, str, str, str] | None


def _figure_jobs(inp: _Inputs) -> list[tuple[str, str | None, Run | None]]:
    """Every figure the report draws, in page order: (kind, axis, run)."""
    model, runs = inp.model, inp.runs
    jobs: list[tuple[str, str | None, Run | None]] = []
    for axis_name, axis in model["axes"].items():
        if axis.get("selection"):
            jobs.append(("selection", axis_name, None))
            if axis["selection"].get("ec_curve"):
                jobs.append(("ec", axis_name, None))
    for run in runs:
        for axis_name in run.target_names:
            jobs.append(("runs", axis_name, run))
            if model["axes"][axis_name].get("effects"):
                jobs.append(("effects", axis_name, run))
                if run is runs[0] and fold_stages(model["axes"][axis_name]):
                    jobs.append(("folds", axis_name, None))
            jobs.append(("hysteresis", axis_name, run))
    if inp.matrix is not None:
        jobs.append(("protocols", None, None))
    if inp.ranges:
        jobs += [("window", None, run) for run in runs]
    jobs += [("service", axis_name, run) for run in runs
             for axis_name in inp.service.get(str(run.path), {})]
    return jobs


def _fig_selection(inp: _Inputs, axis_name: str, axis: dict, run: Run | None) -> Drawn:
    fig_obj, title, caption = selection_figure(axis_name, axis, inp.limit,
                                                inp.model.get("training", {}).get("groups"))
    return fig_obj, title, caption, f"selection_{_slug(axis_name)}.png"


def _fig_ec(inp: _Inputs, axis_name: str, axis: dict, run: Run | None) -> Drawn:
    sel = axis["selection"]
    rule = count_rule(sel, inp.model)
    cap = int(inp.model.get("training", {}).get("max_sensors") or 0) or None
    fig_obj = plots.ec_curve(axis_name, sel["ec_curve"], int(sel.get("chosen_count", 0)),
                             sel.get("ec_subsets"), sel.get("ec_errors_um"), rule, cap,
                             sel.get("ec_fold_errors_um"))
    errors = sel.get("ec_errors_um") or []
    u = unit_text(axis_name)
    caption = ("EC<sub>i</sub> = (S<sub>i</sub>/S<sub>1</sub>)·(i/c) trades the error "
               "of the best i-sensor model against its size. The circled point fixes "
               "how many sensors the selection chose: "
               + {"ec": "the smallest EC (paper 000).",
                  "min": "the smallest out-of-fold error S<sub>i</sub> (an error on data "
                         "the fit did not see already rises when a model is too big).",
                  "cap": f"the --max-sensors cap of {cap}: the out-of-fold error "
                         f"S<sub>i</sub> is smallest at "
                         f"{int(np.argmin(errors)) + 1 if errors else '?'} sensors "
                         f"({min(errors) if errors else math.nan:.3g} {u} against "
                         f"{errors[cap - 1] if errors and cap else math.nan:.3g} {u} at "
                         f"{cap}), beyond what the box allows per axis."}[rule])
    swaps = sel.get("refinement") or []
    if swaps:
        caption += " Group refinement then swapped " + ", ".join(
            f"{html.escape(w['removed'])} → {html.escape(w['added'])} "
            f"({w['error_before_um']:.3g} → {w['error_after_um']:.3g} {u})"
            for w in swaps) + "."
    dropped = [n for n in sel.get("sensors", []) if n not in box_sensors(axis)]
    if dropped:
        caption += (" The channel budget later dropped "
                    + html.escape(", ".join(dropped)) + ": the box reads "
                    + html.escape(", ".join(box_sensors(axis))) + ".")
    return (fig_obj, f"{axis_name}: evaluation criterion", caption,
            f"ec_{_slug(axis_name)}.png")


def _fig_run(inp: _Inputs, axis_name: str, axis: dict, run: Run) -> Drawn:
    """The run against every model's prediction; fills the run's row of the error table."""
    measured = run.target(axis_name)
    preds = {"our model": inp.prediction(axis_name, run)}
    drift = {"measured": iso230_drift(run.time_s, measured),
             "compensated": iso230_drift(run.time_s, measured - preds["our model"])}
    for peer_name, per_run in inp.peer_models.items():
        if (run.path, axis_name) in per_run:
            preds[peer_name] = per_run[(run.path, axis_name)]
    metrics = axis.get("metrics", {})
    promised = metrics.get("promised_rmse_um")
    fig_obj = plots.run_fit(run.name, axis_name, run.time_s, measured, preds,
                            None if promised is None else
                            (float(promised), metrics.get("promised_fold_rmse_um") or []))
    entry = inp.run_table.setdefault(run.name, {})
    entry[axis_name] = {
        "raw_rms_um": plots.rms(measured),
        "residual_rms_um": {k: plots.rms(measured - v) for k, v in preds.items()},
        "in_training": in_training(inp.model, run),
        "drift": drift,
    }
    baseline = axis.get("baseline")
    if baseline and "terms" in baseline:  # where the loop started, so before/after is visible
        entry[axis_name]["baseline_rms_um"] = plots.rms(
            measured - predict(baseline["intercept"], baseline["terms"], run, inp.period,
                               inp.ref))
    caption = ("Top: the measured displacement and what each model predicts from what "
               "the box measures. Bottom: what is left (RMS in the legend)"
               + (f"; the shaded band is ± the RMS host train promised: "
                  f"{html.escape(str(metrics.get('promise') or promised))} (from its nested "
                  "folds, docs/training.md), dotted the worst fold."
                  if promised is not None else ".")
               + (" This run was used for training." if entry[axis_name]["in_training"]
                  else " The model never saw this run."))
    return (fig_obj, f"{run.name}, {axis_name}", caption,
            f"run_{_slug(run.name)}_{_slug(axis_name)}.png")


def _fig_window(inp: _Inputs, axis_name: str | None, axis: dict | None, run: Run) -> Drawn:
    assert inp.ranges is not None
    used = {n: r for n, r in inp.ranges.items()
            if n in run.sensor_names or n in run.aux_names}
    fig_obj = plots.training_window(
        run.name, run.time_s, {n: run.column(n) for n in used},
        {n: (r["min"], r["max"]) for n, r in used.items()}, TOLERANCE_SHARE)
    caption = ("Each input the model reads, scaled so that 0 and 1 are the lowest and "
               "highest value it had in training. Inside the green band the model "
               "interpolates; beyond the dashed lines (5 % of the range further) it "
               "extrapolates (for a thermocouple the box raises EXTRAP there)."
               + (" The model never saw this run." if not in_training(inp.model, run)
                  else " This run was used for training, so it stays inside."))
    return (fig_obj, f"{run.name}: inputs against their training range", caption,
            f"window_{_slug(run.name)}.png")


def _fig_effects(inp: _Inputs, axis_name: str, axis: dict, run: Run) -> Drawn:
    """The residual before and after each effect the loop added (after the run's figure,
    whose row of the error table it extends)."""
    stages = effect_stages(axis, axis_name, run, inp.period, inp.ref)
    if len(stages) < 2:
        return None
    fig_obj = plots.residual_steps(run.name, axis_name, run.time_s,
                                   [(s["legend"], s["residual"]) for s in stages],
                                   dropped=[s["dropped"] for s in stages])
    inp.run_table[run.name][axis_name]["stages_rms_um"] = [
        {"stage": s["label"], "rms_um": plots.rms(s["residual"]), "effect": s.get("name"),
         "dropped": s["dropped"], "box": s["box"]} for s in stages]
    caption = ("Residual of the temperature-only baseline and after each effect the "
               "close-the-loop step added (RMS on this run in the legend). "
               + effects_caption(stages))
    unexplained = axis.get("unexplained") or {}
    if unexplained.get("message"):
        caption += (" Still unexplained"
                    + (" (said of the model before the channel budget)"
                       if axis.get("channel_budget_after_effects") else "")
                    + ": " + html.escape(str(unexplained["message"]).rstrip(". "))
                    + ".")
    return (fig_obj, f"{run.name}, {axis_name}: effects added to close the loop", caption,
            f"effects_{_slug(run.name)}_{_slug(axis_name)}.png")


def _fig_folds(inp: _Inputs, axis_name: str, axis: dict, run: Run | None) -> Drawn:
    rows = fold_stages(axis)
    fig_obj = plots.fold_errors(axis_name, [r["stage"] for r in rows],
                                [r["rmse_um"] for r in rows], [r["folds_um"] for r in rows],
                                [r["dropped"] for r in rows])
    caption = ("The validation RMSE of the baseline and after each effect, with error "
               "bars from the best to the worst validation fold and every fold as a "
               "dot (from the effect search's own record). A gain smaller than the "
               "spread between folds would be noise; the search only keeps effects that "
               "improve every fold that exercises them.")
    whys = list(dict.fromkeys(r["why"] for r in rows if r.get("why")))
    if whys:
        caption += (" Grey: not in the box's model, dropped because "
                    + "; or because ".join(html.escape(w) for w in whys) + ".")
    return (fig_obj, f"{axis_name}: validation error per stage, across the folds", caption,
            f"folds_{_slug(axis_name)}.png")


def _fig_hysteresis(inp: _Inputs, axis_name: str, axis: dict, run: Run) -> Drawn:
    sensor = most_important_sensor(axis, run, inp.period)
    if sensor is None:
        return None
    measured = run.target(axis_name)
    residual = measured - inp.prediction(axis_name, run)
    fig_obj = plots.hysteresis(run.name, axis_name, sensor, run.column(sensor),
                               measured, residual, inp.period)
    caption = (f"{sensor} contributes most to the {axis_name} prediction on this run. "
               "Heating (red) and cooling (blue) follow different paths before "
               "compensation; after it the loop should collapse towards zero.")
    return (fig_obj, f"{run.name}, {axis_name} against {sensor}", caption,
            f"hysteresis_{_slug(run.name)}_{_slug(axis_name)}.png")


def _fig_protocols(inp: _Inputs, axis_name: str | None, axis: dict | None,
                   run: Run | None) -> Drawn:
    matrix = inp.matrix
    assert matrix is not None
    fig_obj = plots.protocol_matrix(matrix.train, matrix.test, matrix.values,
                                    matrix.metric, matrix.spread)
    caption = ("Each cell: a model trained on the row's protocol, judged on the "
               "column's. A row that stays low everywhere is the protocol to run.")
    if matrix.spread is not None:
        caption += (" ± is the standard deviation over the repeats (other simulated "
                    "days): a lead smaller than it is noise.")
    if matrix.verdict and matrix.verdict.get("reason"):
        caption += (" Verdict: " + ("winner " + html.escape(matrix.verdict["winner"])
                                    + ": " if matrix.verdict.get("winner") else
                                    "no winner: ")
                    + html.escape(str(matrix.verdict["reason"])) + ".")
    return fig_obj, "Protocol comparison", caption, "protocols.png"


def _fig_service(inp: _Inputs, axis_name: str, axis: dict, run: Run) -> Drawn:
    day = inp.service[str(run.path)][axis_name]
    m = day["metrics"]
    fig_obj = plots.service_day(run.name, axis_name, run.time_s, day["measured"], day["static"],
                                day["updated"], day["probe_only"], day["index"], day["value"],
                                day["accepted"])
    u = html.escape(unit_text(axis_name))
    caption = (
        "What a touch probe on a reference artifact adds in service (docs/service.md). Red "
        "marks: the readings (" + html.escape(inp.service_source[str(run.path)]) + "), "
        "a dot where the gate accepted one, a cross where it refused one and nothing moved. "
        "<b>Static</b> is the model alone; <b>updated</b> adds the estimator's correction "
        "before the box's step limit, which is what the box outputs; <b>probe-only</b> is "
        "re-touching off without a model, the last reading held. Bottom: what each leaves of "
        f"the measured displacement; lower is better. RMS here: updated {m['rmse_um']:.2f} {u}, "
        f"static {m['static_rmse_um']:.2f} {u}, probe-only {m['probe_only_rmse_um']:.2f} {u} "
        f"({m['probes']} readings, {m['refused']} refused; the same numbers as "
        "<code>host evaluate</code> with these readings).")
    return (fig_obj, f"{run.name}, {axis_name}: a day in service", caption,
            f"service_{_slug(run.name)}_{_slug(axis_name)}.png")


FIGURES = {"selection": _fig_selection, "ec": _fig_ec, "runs": _fig_run,
           "window": _fig_window, "effects": _fig_effects, "folds": _fig_folds,
           "hysteresis": _fig_hysteresis, "protocols": _fig_protocols,
           "service": _fig_service}


def build_report(model_path: str | Path, run_paths: list[str | Path], out_dir: str | Path,
                 protocols: str | Path | None = None, peers: bool = True,
                 fill_gaps: int = 0, quiet: bool = False,
                 hil: list[str | Path] | None = None, fmt: CsvFormat | None = None,
                 reference: str | None = None,
                 locations: str | Path | None = None,
                 probes: ProbePlan | None = None) -> Report:
    """Render every figure and write ``out_dir/index.html``; inputs are all checked first.

    ``locations``: a CSV with columns ``sensor`` and ``location`` (where each thermocouple
    sits on the machine) for the wiring sheet. ``probes``: synthesise probe readings on every
    run (``--probe-every`` ...); without it a run's logged ``probe_<axis>`` columns are
    used. Either way the report draws a day in service per run and axis with readings."""
    model = read_model(model_path)
    where = load_locations(locations) if locations else {}
    ref = model_reference(model, reference)  # measured and predicted drift judged alike
    raw = load_report_runs(model, list(run_paths), fill_gaps, fmt)
    runs = [referenced(run, ref) for run in raw]
    matrix = load_protocols(protocols) if protocols else None
    hil_results = [load_hil(p) for p in hil or []]
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    report = Report(out)
    spec = spec_of(model)
    inp = _Inputs(model, spec, runs, ref, spec.sample_period_s,
                  peer_predictions(model, runs) if peers else {}, matrix,
                  training_ranges(model), delay_limit_s(model))
    for run in raw:  # issue 42: host evaluate's service computation on the unreferenced run
        readings = readings_for(model, run, probes, reference, fmt)
        if readings is not None:
            day = service_day(model, run, readings, reference)
            if day:
                inp.service[str(run.path)] = day
                inp.service_source[str(run.path)] = readings.source
    for kind, axis_name, run in progress(_figure_jobs(inp), "report figures", quiet=quiet):
        axis = model["axes"][axis_name] if axis_name else None
        drawn = FIGURES[kind](inp, axis_name, axis, run)
        if drawn is None:
            continue
        fig_obj, title, caption, file = drawn
        clipped = _save(fig_obj, out / file)
        groups = selection_groups(axis) if kind == "selection" else None
        if groups and all(len(g["members"]) == 1 for g in groups):
            groups = None  # one sensor per group: the caption says why, a table adds nothing
        report.figures.append(Figure(kind, kind, title, caption, file, groups, clipped))
    report.summary = _summary(model_path, inp, report, hil_results, where)
    _write_wiring_csv(out / "wiring.csv", report.summary["wiring"])
    write_text_atomic(out / "summary.json", json.dumps(report.summary, indent=2, default=_json_num))
    write_text_atomic(report.index, render_html(model, report))
    return report


def _summary(model_path: str | Path, inp: _Inputs, report: Report, hil_results: list[dict],
             where: dict[str, str]) -> dict:
    """summary.json: the axes, the error table, the coefficients and the wiring sheet."""
    model = inp.model
    summary: dict = {
        "model": str(model_path),
        "model_hash": model_hash(model),
        "axes": summary_rows(model),
        "runs": inp.run_table,
        "outside_training": {run.name: outside_training(model, run) for run in inp.runs},
        "figures": [f.file for f in report.figures],
        # legends and labels cut off at a PNG's edge (plots.clipped_artists): none expected
        "figures_clipped": {f.file: f.clipped for f in report.figures if f.clipped},
    }
    if hil_results:
        summary["hil"] = hil_results
    if inp.service:  # host evaluate --json's per-axis service numbers, per run
        summary["service"] = {
            run.name: {"probes": inp.service_source[str(run.path)],
                       "axes": {a: d["metrics"] for a, d in inp.service[str(run.path)].items()}}
            for run in inp.runs if str(run.path) in inp.service}
    train_runs = training_runs(model)
    units = input_units(model)
    summary["coefficients"] = [
        coefficient_table(name, axis, train_runs, inp.period, units, inp.ref)
        for name, axis in model["axes"].items()]
    summary["wiring"] = wiring_rows(model, where)
    summary["locations_given"] = bool(where)
    if inp.matrix is not None:
        summary["protocols"] = {"train": inp.matrix.train, "test": inp.matrix.test,
                                "values": inp.matrix.values.tolist(),
                                "metric": inp.matrix.metric}
    return summary


def _write_wiring_csv(path: Path, rows: list[dict]) -> None:
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["box_channel", "sensor", "tc_type", "location", "axes", "trained_min_c",
                "trained_max_c"])
    for r in rows:
        w.writerow([r["channel"], r["sensor"], r["tc_type"], r["location"] or "",
                    " ".join(r["axes"]), r["trained_min_c"] if r["trained_min_c"] is not None
                    else "", r["trained_max_c"] if r["trained_max_c"] is not None else ""])
    write_text_atomic(path, buf.getvalue())


def _json_num(value):
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(type(value))

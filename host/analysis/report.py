"""`host report`: one self-contained HTML page (plus the PNGs) that tells the model's story.

Why a static page: it opens anywhere without a server or network (images are embedded as data
URIs, the same PNGs are written beside it for slides), and it is reproducible from the model
file and the runs alone. The figures follow paper 000 (sensor plane, EC curve) and add what the
papers do not show: unseen runs, peers, the effects added to close the loop, the heating and
cooling paths and the fixed-point error bound. Figures are drawn in ``host.analysis.plots``.
"""

from __future__ import annotations

import base64
import csv
import dataclasses
import html
import io
import json
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from contract.errors import InputError
from contract.model_file import channel_ranges, read_model
from contract.terms import TEMPERATURE_KINDS, Term
from contract.tilt import available_axes, model_tilts, unit_text
from host.analysis import plots
from host.analysis.evaluate import model_reference
from host.analysis.metrology import (
    VIF_NOT_IDENTIFIABLE,
    coefficient_table,
    iso230_drift,
    wiring_rows,
)
from host.analysis.service import readings_for, service_day
from host.fitting import NO_REFERENCE, Reference, design_matrix, fit_linear
from host.io import CsvFormat, Run, load_run, read_header
from host.io.runs import missing_sensors
from host.progress import progress
from host.selection import default_max_lag
from host.service import ProbePlan
from host.train import (
    TOLERANCE_SHARE,
    box_effects_evidence,
    box_model_note,
    dropped_reason,
    input_units,
    outside_training,
    ridge_lags_note,
    training_ranges,
)


class ReportError(InputError):
    """Input the report cannot use (the message names the file and what is wrong)."""


# ---------------------------------------------------------------- model and predictions

def axis_terms(axis: dict) -> tuple[list[Term], np.ndarray]:
    terms = [Term.from_json(t) for t in axis["terms"]]
    coefs = np.array([float(t["coef"]) for t in axis["terms"]], dtype=float)
    return terms, coefs


def predict(intercept: float, term_dicts: list[dict], run: Run, period_s: float,
            reference: Reference = NO_REFERENCE) -> np.ndarray:
    """Float prediction of one axis on a whole run (filters start at the run's first sample),
    referenced as the box outputs it (``start``: the change since the run's start)."""
    terms = [Term.from_json(t) for t in term_dicts]
    coefs = np.array([float(t["coef"]) for t in term_dicts], dtype=float)
    X = design_matrix(terms, run.columns(), period_s)
    return reference.apply(float(intercept) + (X @ coefs if coefs.size else np.zeros(len(X))))


def sensor_contributions(axis: dict, run: Run, period_s: float) -> dict[str, np.ndarray]:
    """Each sensor's summed contribution (µm) over the run, from all its terms."""
    terms, coefs = axis_terms(axis)
    out: dict[str, np.ndarray] = {}
    columns = run.columns()
    for term, coef in zip(terms, coefs, strict=True):
        if term.source is None or term.source not in run.sensor_names:
            continue
        value = coef * design_matrix([term], columns, period_s)[:, 0]
        out[term.source] = out.get(term.source, 0.0) + value
    return out


def box_sensors(axis: dict) -> list[str]:
    """Temperature sources of the axis's final terms, in term order: what the box reads."""
    out: list[str] = []
    for t in axis["terms"]:
        if t["kind"] in TEMPERATURE_KINDS and t.get("source") and t["source"] not in out:
            out.append(t["source"])
    return out


def dropped_sensors(axis: dict) -> list[str]:
    """Sensors the channel budget took away from this axis after selection and effects."""
    after = axis.get("channel_budget_after_effects") or {}
    return list(after.get("dropped_sensors") or [])


def effect_label(effect: dict) -> str:
    """An effect's name, marked when it is not in the box's model (dropped_reason) or when the
    box's ridge models it with its own lags (ridge_lags_note)."""
    name = str(effect.get("name", effect.get("kind", "?")))
    why = dropped_reason(effect)
    if why:
        return f"{name} (dropped: {why})"
    lags = ridge_lags_note(effect)
    return f"{name} ({lags})" if lags else name


def most_important_sensor(axis: dict, run: Run, period_s: float) -> str | None:
    """The sensor whose contribution varies most over the run: the temperature that drives it."""
    contrib = sensor_contributions(axis, run, period_s)
    if not contrib:
        return None
    return max(contrib, key=lambda s: float(np.std(contrib[s])))


# ---------------------------------------------------------------- inputs

def _header(path: Path, fmt: CsvFormat | None = None) -> list[str]:
    if not path.is_file():
        raise ReportError(f"{path}: run file not found")
    return read_header(path, fmt)


def referenced(run: Run, reference: Reference) -> Run:
    """The run with its measured displacements referenced like the model's output."""
    if reference.kind == "none" or run.displacements is None:
        return run
    disp = np.column_stack([reference.apply(run.displacements[:, i])
                            for i in range(run.displacements.shape[1])])
    return dataclasses.replace(run, displacements=disp)


def load_report_runs(model: dict, paths: list[str | Path], fill_gaps: int = 0,
                     fmt: CsvFormat | None = None) -> list[Run]:
    """Load each run with the model's axes it has, every temperature and the model's aux."""
    training = model.get("training", {})
    sensors = training.get("sensors", "T*")
    aux_names = [a["name"] for a in model.get("aux", [])]
    needed = {c["sensor"] for c in model["channels"]}
    tilts = model_tilts(model)
    runs = []
    for p in paths:
        path = Path(p)
        header = _header(path, fmt)
        targets = available_axes(header, list(model["axes"]), tilts)
        if not targets:
            raise ReportError(f"{path}: none of the model's axes "
                              f"({', '.join(model['axes'])}) is a column of this run")
        missing = sorted(needed - set(header))
        if missing:
            raise ReportError(f"{path}, line 1: " + missing_sensors(
                missing, [h for h in header if h not in ("time_s", *targets)],
                "the model reads them"))
        ranges = channel_ranges(model)
        run = load_run(path, targets, sensors, aux_names, fill_gaps=fill_gaps, fmt=fmt,
                       temperature_ranges=ranges, tilts=tilts)
        absent = sorted(needed - set(run.sensor_names))
        if absent:  # the model's sensors may lie outside the training glob: add them
            run = load_run(path, targets, sorted(set(run.sensor_names) | needed), aux_names,
                           fill_gaps=fill_gaps, fmt=fmt, temperature_ranges=ranges, tilts=tilts)
        runs.append(run)
    return runs


@dataclass
class ProtocolMatrix:
    train: list[str]
    test: list[str]
    values: np.ndarray
    metric: str
    spread: np.ndarray | None = None  # standard deviation over repeats, same shape
    verdict: dict | None = None  # `host compare-protocols`' winner (or none) and why


def load_protocols(path: str | Path) -> ProtocolMatrix:
    """A train × test error matrix from `host compare-protocols` (JSON or CSV).

    JSON: ``{"metric": ..., "train": [...], "test": [...], "matrix": [[...]]}`` or a list of
    rows ``{"train": .., "test": .., <metric>: ..}``; CSV: rows with train, test and a value.
    """
    path = Path(path)
    if not path.is_file():
        raise ReportError(f"{path}: protocol comparison file not found")
    if path.suffix.lower() == ".csv":
        with path.open(newline="") as fh:
            rows = list(csv.DictReader(fh))
        return _matrix_from_rows(path, rows, None)
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ReportError(f"{path}: not valid JSON (line {exc.lineno}): {exc.msg}") from None
    if isinstance(data, dict) and "matrix" in data:
        train = [str(x) for x in data.get("train") or data.get("rows") or []]
        test = [str(x) for x in data.get("test") or data.get("columns") or []]
        values = np.array([[math.nan if v is None else float(v) for v in row]
                           for row in data["matrix"]], dtype=float)
        if values.shape != (len(train), len(test)):
            raise ReportError(f"{path}: matrix is {values.shape[0]}×{values.shape[1]} but there "
                              f"are {len(train)} train and {len(test)} test labels")
        sd = (data.get("settings") or {}).get("mean_rmse_sd_over_repeats_um")
        spread = None
        if sd is not None:
            spread = np.array([[math.nan if v is None else float(v) for v in row] for row in sd],
                              dtype=float)
            if spread.shape != values.shape:
                spread = None
        return ProtocolMatrix(train, test, values, str(data.get("metric", "RMSE (µm)")), spread,
                              data.get("verdict"))
    rows = data.get("results", data.get("rows")) if isinstance(data, dict) else data
    if not isinstance(rows, list):
        raise ReportError(f"{path}: expected a 'matrix' or a list of result rows")
    metric = data.get("metric") if isinstance(data, dict) else None
    return _matrix_from_rows(path, rows, metric)


def _matrix_from_rows(path: Path, rows: list, metric: str | None) -> ProtocolMatrix:
    if not rows:
        raise ReportError(f"{path}: no rows")
    keys = list(rows[0])
    train_key = next((k for k in keys if k.lower() in ("train", "trained_on", "train_protocol")),
                     None)
    test_key = next((k for k in keys if k.lower() in ("test", "judged_on", "test_protocol")),
                    None)
    if train_key is None or test_key is None:
        raise ReportError(f"{path}: rows need 'train' and 'test' fields (have: {', '.join(keys)})")
    if metric is None or metric not in keys:
        candidates = [k for k in keys if "rmse" in k.lower()] or \
                     [k for k in keys if k not in (train_key, test_key)]
        metric = candidates[0]
    train = list(dict.fromkeys(str(r[train_key]) for r in rows))
    test = list(dict.fromkeys(str(r[test_key]) for r in rows))
    values = np.full((len(train), len(test)), math.nan)
    for n, r in enumerate(rows, start=2):
        try:
            v = float(r[metric])
        except (TypeError, ValueError):
            raise ReportError(f"{path}: row {n}: '{metric}' is not a number: "
                              f"{r.get(metric)!r}") from None
        values[train.index(str(r[train_key])), test.index(str(r[test_key]))] = v
    unit = " (µm)" if metric.endswith("_um") else ""
    return ProtocolMatrix(train, test, values, metric + unit)


def load_hil(path: str | Path) -> dict:
    """A `python -m hil replay --json` result: the box's own output on a replayed run."""
    path = Path(path)
    if not path.is_file():
        raise ReportError(f"{path}: HIL result file not found")
    try:
        doc = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ReportError(f"{path}: not valid JSON (line {exc.lineno}): {exc.msg}") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("axes"), dict):
        raise ReportError(f"{path}: not a HIL replay result (no 'axes')")
    return {"file": str(path), **doc}


# ---------------------------------------------------------------- report

@dataclass
class Figure:
    key: str
    section: str
    title: str
    caption: str
    file: str
    groups: list[dict] | None = None  # selection figures: paper 000's Table 1 beside it
    clipped: list[str] = field(default_factory=list)  # legends/labels cut off at the edge


@dataclass
class Report:
    out_dir: Path
    figures: list[Figure] = field(default_factory=list)
    summary: dict = field(default_factory=dict)

    @property
    def index(self) -> Path:
        return self.out_dir / "index.html"


SECTIONS = [
    ("selection", "1. Sensor selection (paper 000, Fig. 7)"),
    ("ec", "2. How many sensors (paper 000, Fig. 8)"),
    ("runs", "3. Prediction on each run"),
    ("effects", "4. Effects added to close the loop"),
    ("folds", "4b. The effects' gains against the fold-to-fold spread"),
    ("hysteresis", "5. Heating and cooling paths (pseudo-hysteresis)"),
    ("protocols", "6. Which test protocol to run"),
    ("window", "7. Inside or beyond the training range"),
    ("service", "8. A day in service: the touch probe updates the model (issue 42)"),
]


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text).strip("_") or "x"


def _save(fig, path: Path) -> list[str]:
    """Write the PNG; what of it is cut off at the image's edge (plots.clipped_artists)."""
    return plots.save_png(fig, path)


def _fmt(value, digits: int = 2, unit: str = "") -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "—"
    return f"{value:.{digits}f}{unit}"


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
    fig_obj, title, caption = _selection_figure(axis_name, axis, inp.limit,
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
    preds = {"our model": predict(axis["intercept"], axis["terms"], run, inp.period, inp.ref)}
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
        "in_training": _in_training(inp.model, run),
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
               + (" The model never saw this run." if not _in_training(inp.model, run)
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
    residual = measured - predict(axis["intercept"], axis["terms"], run, inp.period, inp.ref)
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
    inp = _Inputs(model, runs, ref, float(model["sample_period_s"]),
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
    _write_atomic(out / "summary.json", json.dumps(report.summary, indent=2, default=_json_num))
    _write_atomic(report.index, render_html(model, report))
    return report


def _summary(model_path: str | Path, inp: _Inputs, report: Report, hil_results: list[dict],
             where: dict[str, str]) -> dict:
    """summary.json: the axes, the error table, the coefficients and the wiring sheet."""
    model = inp.model
    summary: dict = {
        "model": str(model_path),
        "model_hash": _model_hash(model),
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


def load_locations(path: str | Path) -> dict[str, str]:
    """sensor -> where it sits on the machine, from a CSV with columns sensor, location."""
    path = Path(path)
    if not path.is_file():
        raise ReportError(f"{path}: locations file not found")
    with path.open(newline="", encoding="utf-8-sig") as fh:
        reader = csv.DictReader(fh)
        fields = [f.strip().lower() for f in reader.fieldnames or []]
        if "sensor" not in fields or "location" not in fields:
            raise ReportError(f"{path}: needs the columns 'sensor' and 'location' (has: "
                              f"{', '.join(reader.fieldnames or [])})")
        out = {}
        for n, row in enumerate(reader, start=2):
            row = {k.strip().lower(): (v or "").strip() for k, v in row.items() if k}
            if not row["sensor"]:
                raise ReportError(f"{path}: line {n}: empty sensor name")
            out[row["sensor"]] = row["location"]
    return out


def _write_wiring_csv(path: Path, rows: list[dict]) -> None:
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["box_channel", "sensor", "tc_type", "location", "axes", "trained_min_c",
                "trained_max_c"])
    for r in rows:
        w.writerow([r["channel"], r["sensor"], r["tc_type"], r["location"] or "",
                    " ".join(r["axes"]), r["trained_min_c"] if r["trained_min_c"] is not None
                    else "", r["trained_max_c"] if r["trained_max_c"] is not None else ""])
    _write_atomic(path, buf.getvalue())


def training_runs(model: dict) -> list[Run]:
    """The model's training runs with its axes and sensors, when readable here (else [])."""
    training = model.get("training", {})
    paths = [Path(p) for p in training.get("runs", [])]
    if not paths or not all(p.is_file() for p in paths):
        return []
    needed = sorted({c["sensor"] for c in model["channels"]})
    aux = [a["name"] for a in model.get("aux", [])]
    try:
        tilts = model_tilts(model)
        return [load_run(p, available_axes(_header(p), list(model["axes"]), tilts), needed, aux,
                         tilts=tilts) for p in paths]
    except (ValueError, InputError):
        return []


def _json_num(value):
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(type(value))


def _write_atomic(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)


def _model_hash(model: dict) -> str | None:
    try:
        from codegen import model_hash  # lands with the code generator
    except ImportError:
        return None
    return model_hash(model)


def _in_training(model: dict, run: Run) -> bool:
    names = {Path(p).stem for p in model.get("training", {}).get("runs", [])}
    return run.name in names


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


def _selection_figure(axis_name: str, axis: dict, limit_s: float | None = None,
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
    added = [n for n in box if n not in selected]
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
    caption += _grouping_note(axis_name, axis, groups_requested)
    if limit_s:
        at_edge = [n for n, d in zip(names, delays, strict=True)
                   if math.isfinite(d) and abs(d) >= limit_s - 1e-6]
        caption += (f" Triangles: delay at the limit of the search (±{limit_s / 3600:.3g} h): "
                    + (e(", ".join(at_edge)) if at_edge else "none")
                    + (", whose true delay may be longer." if at_edge else "."))
    caption += f" Method: {e(str(sel.get('method', '?')))}."
    return fig, title, caption


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


K_CORRELATED = 4  # paper 002's four most correlated sensors


def _abs_correlation(X: np.ndarray, y: np.ndarray) -> np.ndarray:
    Xc, yc = X - X.mean(axis=0), y - y.mean()
    den = np.sqrt((Xc ** 2).sum(axis=0) * (yc ** 2).sum())
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.where(den > 0, (Xc.T @ yc) / den, 0.0)
    return np.abs(r)


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
        train_runs = [load_run(p, available_axes(_header(p), axes, tilts),
                               training.get("sensors", "T*"), tilts=tilts) for p in paths]
    except ValueError:
        return {}
    names = train_runs[0].sensor_names
    if any(r.sensor_names != names for r in train_runs) or \
            not all(set(names) <= set(r.sensor_names) for r in runs):
        return {}
    k = min(K_CORRELATED, len(names))
    labels = ("OLS, all sensors", f"{k} most correlated (paper 002)")
    out: dict[str, dict[tuple[str, str], np.ndarray]] = {label: {} for label in labels}
    for axis in axes:
        have = [r for r in train_runs if axis in r.target_names]
        if not have:
            continue
        X = np.vstack([ref.apply(r.temperatures) for r in have])
        y = np.concatenate([ref.apply(r.target(axis)) for r in have])
        top = np.argsort(-_abs_correlation(X, y), kind="stable")[:k]
        for label, idx in zip(labels, (np.arange(len(names)), top), strict=True):
            fit = fit_linear(X[:, idx], y)
            cols = [names[i] for i in idx]
            for run in runs:
                if axis in run.target_names:
                    Xr = np.column_stack([run.column(c) for c in cols])
                    out[label][(run.path, axis)] = ref.apply(fit.predict(Xr))
    return out


# ---------------------------------------------------------------- HTML

TEMPLATES = Path(__file__).with_name("templates")


def _status_counts_text(counts: dict | None) -> str:
    if not counts:
        return ""
    text = " Status bits the box raised: " + ", ".join(
        f"{name} on {n} sample{'s' if n != 1 else ''}" for name, n in counts.items()) + "."
    if "EXTRAP" in counts:
        text += (" EXTRAP: a reading beyond its training window, so the correction is an "
                 "extrapolation (still applied).")
    return text


def _beyond_text(rows: list[dict] | None) -> str:
    if rows is None:
        return "not stored in this model"
    if not rows:
        return "none"
    return ", ".join(
        f"{r['input']} {'+' if r['run_max'] > r['train_max'] else '−'}"
        + (f"{100 * r['beyond_share']:.0f} %" if r["beyond_share"] is not None
           else f"{r['beyond']:.3g}")
        + f" ({r['samples_outside_pct']:.0f} % of the run)" for r in rows)


def _span_text(values: list[float] | None) -> str:
    """A gain across the folds: ``lowest … highest (n folds)``, or — without folds."""
    if not values:
        return "—"
    if len(values) == 1:
        return f"{values[0]:.3f} (1 fold)"
    return f"{min(values):.3f} … {max(values):.3f} ({len(values)} folds)"


def _duration_text(seconds: float) -> str:
    """A time constant as a reader thinks of it: 900 s, 1 h, 4 h."""
    if seconds >= 3600 and seconds % 1800 == 0:
        return f"{seconds / 3600:g} h"
    return f"{seconds:g} s"


def _environment():
    import jinja2

    env = jinja2.Environment(loader=jinja2.FileSystemLoader(str(TEMPLATES)),
                             autoescape=jinja2.select_autoescape(["html", "j2"]),
                             trim_blocks=False)
    env.filters["num"] = lambda v, digits=2: _fmt(v, digits)
    env.filters["nm"] = lambda v: _fmt(None if v is None else v * 1000, 3)
    env.filters["span"] = _span_text
    env.filters["duration"] = _duration_text
    env.filters["mode"] = lambda gain, tau: next(
        (m["amplitude_um_per_k"] for m in gain["modes"] if m["tau_s"] == tau), None)
    env.globals["vif_limit"] = VIF_NOT_IDENTIFIABLE
    env.globals["status_counts"] = _status_counts_text
    env.globals["hil_checks"] = lambda hil: ", ".join(
        f"{k} {'passed' if v else 'FAILED'}" for k, v in (hil.get("checks") or {}).items()) \
        or "—"
    return env


def render_html(model: dict, report: Report) -> str:
    """The page, from ``templates/report.html.j2`` (jinja2, autoescaped; captions are built
    escaped and marked safe)."""
    summary = report.summary
    models = list(dict.fromkeys(m for per in summary["runs"].values() for a in per.values()
                                for m in a["residual_rms_um"]))
    sections = []
    for key, heading in SECTIONS:
        figs = [f for f in report.figures if f.section == key]
        if figs:
            sections.append({"heading": heading, "figures": [{
                "stem": Path(f.file).stem, "file": f.file, "title": f.title,
                "caption": f.caption, "groups": f.groups,
                "data": base64.b64encode((report.out_dir / f.file).read_bytes()).decode("ascii"),
            } for f in figs]})
    context = {
        "model": model, "summary": summary, "models": models, "sections": sections,
        "validations": sorted({r["validation"] for r in summary["axes"] if r.get("validation")}),
        "beyond": {name: _beyond_text(rows)
                   for name, rows in summary.get("outside_training", {}).items()},
        "coefficients": summary.get("coefficients") or [],
        "wiring": summary.get("wiring") or [],
        "locations_given": summary.get("locations_given", False),
    }
    return _environment().get_template("report.html.j2").render(**context)

"""What `host report` is made of: the model's terms and predictions, the runs referenced as
the model was, the protocol matrix and HIL results files, the wiring locations, and the
page's structure (its figures and sections)."""

from __future__ import annotations

import csv
import dataclasses
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from thermal_comp.contract.errors import InputError
from thermal_comp.contract.model_file import channel_ranges
from thermal_comp.contract.terms import TEMPERATURE_KINDS
from thermal_comp.contract.tilt import available_axes, model_tilts
from thermal_comp.host.fitting import (
    NO_REFERENCE,
    Reference,
    coefficient_terms,
    design_matrix,
    linear_prediction,
)
from thermal_comp.host.io import CsvFormat, Run, load_run, missing_sensors, read_header
from thermal_comp.host.train import (
    dropped_reason,
    ridge_lags_note,
)


class ReportError(InputError):
    """Input the report cannot use (the message names the file and what is wrong)."""


# ---------------------------------------------------------------- model and predictions

def predict(intercept: float, term_dicts: list[dict], run: Run, period_s: float,
            reference: Reference = NO_REFERENCE) -> np.ndarray:
    """Float prediction of a JSON term list on a whole run (the model's axis, its baseline or
    an effect stage: host.fitting.linear_prediction), referenced as the box outputs it
    (``start``: the change since the run's start)."""
    terms, coefs = coefficient_terms(term_dicts)
    return reference.apply(linear_prediction(terms, coefs, intercept, run.columns(), period_s,
                                             run.n_samples))


def sensor_contributions(axis: dict, run: Run, period_s: float) -> dict[str, np.ndarray]:
    """Each sensor's summed contribution (µm) over the run, from all its terms."""
    terms, coefs = coefficient_terms(axis["terms"])
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

def run_header(path: Path, fmt: CsvFormat | None = None) -> list[str]:
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
        header = run_header(path, fmt)
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
    """A `python -m thermal_comp.hil replay --json` result: the box's own output on a replayed
    run."""
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
        return [load_run(p, available_axes(run_header(p), list(model["axes"]), tilts), needed, aux,
                         tilts=tilts) for p in paths]
    except (ValueError, InputError):
        return []


def in_training(model: dict, run: Run) -> bool:
    names = {Path(p).stem for p in model.get("training", {}).get("runs", [])}
    return run.name in names


# ---------------------------------------------------------------- the page's structure
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


def fmt_value(value, digits: int = 2, unit: str = "") -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "—"
    return f"{value:.{digits}f}{unit}"

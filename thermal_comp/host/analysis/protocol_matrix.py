"""Which thermal test should a model be trained on? Paper 002's question, as a test matrix.

For each protocol, a model is trained on one run of that protocol and tested on runs of every
protocol, each on another day (its own seed), plus a ``random`` production day. A row of the
matrix is a training protocol, a column a test run, a cell the test RMSE. Simulated runs come
from ``host.sim.simulator``; measured runs can be given instead (``--runs constant=a.csv ...``),
in which case a protocol with a single run is tested on that same run (marked in-sample).

Training is ``host.train.train_model`` (the project's selection: paper 000 with out-of-fold
validation), static by default like paper 002's regression; ``fit_effects`` lets the effect
search (``host.effects``) add dynamic terms. Testing is ``host.analysis.evaluate.evaluate_model``.
"""

from __future__ import annotations

import csv
import json
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from thermal_comp.contract.errors import InputError
from thermal_comp.host.io import Run, load_run
from thermal_comp.host.progress import progress
from thermal_comp.host.sim import (
    PROTOCOLS,
    RPM_COLUMN,
    SimConfig,
    build_program,
    simulate,
    write_simulation,
)

PRODUCTION = "production"
AXES = ("dx_um", "dy_um", "dz_um")


class ProtocolComparisonError(InputError):
    """The comparison cannot run on these inputs (bad --runs item, missing column...)."""


@dataclass
class Comparison:
    """RMSE of every (training protocol, test run) pair, per axis."""

    train: list[str]  # training protocol names (rows)
    test: list[str]  # test run labels (columns)
    targets: list[str]
    rmse_um: dict[str, np.ndarray]  # axis -> (rows, cols)
    in_sample: np.ndarray  # (rows, cols) bool: test run is the training run
    runs: dict[str, list[str]]  # label -> paths (training run first)
    models: dict[str, dict] = field(default_factory=dict)  # row -> {axis: terms}
    raw_rms_um: dict[str, dict[str, float]] = field(default_factory=dict)  # col -> axis -> rms
    settings: dict = field(default_factory=dict)

    def mean_rmse_um(self) -> np.ndarray:
        """RMSE averaged over the axes (rows, cols)."""
        return np.mean([self.rmse_um[a] for a in self.targets], axis=0)

    def ranking(self) -> list[tuple[str, float]]:
        """Training protocols by their mean out-of-protocol, out-of-sample RMSE, best first."""
        m = self.mean_rmse_um()
        out = []
        for i, name in enumerate(self.train):
            cols = [j for j, t in enumerate(self.test) if t != name and not self.in_sample[i, j]]
            out.append((name, float(np.mean(m[i, cols])) if cols else math.nan))
        return sorted(out, key=lambda x: (math.isnan(x[1]), x[1]))

    def verdict(self) -> dict:
        """Is there a best training protocol, or is the difference within the noise?

        The score of a protocol is its mean RMSE on the other protocols' runs (``ranking``).
        With repeats (other simulated days) each repeat gives a score per protocol; the spread
        is the larger standard deviation over repeats of the two best protocols' scores. A
        winner is declared only when the gap between the best and the runner-up exceeds that
        spread; with one repeat there is no spread, and no winner is declared.
        """
        ranking = [(n, v) for n, v in self.ranking() if math.isfinite(v)]
        per_repeat = self.settings.get("per_repeat_scores") or []
        sd = {}
        if len(per_repeat) >= 2:
            for name, _ in ranking:
                vals = [r[name] for r in per_repeat if r.get(name) is not None]
                sd[name] = float(np.std(vals, ddof=1)) if len(vals) >= 2 else math.nan
        out: dict = {"repeats": max(1, len(per_repeat)),
                     "scores_um": {n: _none(v) for n, v in ranking},
                     "spread_um": {n: _none(sd.get(n, math.nan)) for n, _ in ranking},
                     "winner": None}
        if len(ranking) < 2:
            out["reason"] = "fewer than two training protocols with a score"
            return out
        (best, b), (second, s2) = ranking[0], ranking[1]
        gap = s2 - b
        spread = max(sd.get(best, math.nan), sd.get(second, math.nan))
        out.update(best=best, runner_up=second, gap_um=_none(gap), spread_used_um=_none(spread))
        if not math.isfinite(spread):
            out["reason"] = (f"{best} {b:.2f} um vs {second} {s2:.2f} um from one repeat: no "
                             "spread to judge the gap against (use --repeats 3 or more)")
        elif gap > spread:
            out["winner"] = best
            out["reason"] = (f"{best} {b:.2f} um beats {second} {s2:.2f} um by {gap:.2f} um, "
                             f"more than the spread over repeats ({spread:.2f} um)")
        else:
            out["reason"] = (f"{best} {b:.2f} um vs {second} {s2:.2f} um: the gap {gap:.2f} um "
                             f"is within the spread over repeats ({spread:.2f} um)")
        return out

    def to_json(self) -> dict:
        return {
            "train": self.train, "test": self.test, "targets": self.targets,
            "rmse_um": {a: _nan_to_none(v) for a, v in self.rmse_um.items()},
            "mean_rmse_um": _nan_to_none(self.mean_rmse_um()),
            # the shape host.analysis.report_data.load_protocols reads: one matrix and its metric
            "metric": "test RMSE, mean of axes (um)", "matrix": _nan_to_none(self.mean_rmse_um()),
            "in_sample": self.in_sample.tolist(),
            "ranking": [{"train": n, "mean_cross_rmse_um": _none(v)} for n, v in self.ranking()],
            "verdict": self.verdict(),
            "raw_rms_um": self.raw_rms_um, "runs": self.runs, "models": self.models,
            "settings": self.settings,
        }

    def rows(self) -> list[dict]:
        """Long table for CSV: one row per (train, test, axis)."""
        out = []
        for i, tr in enumerate(self.train):
            for j, te in enumerate(self.test):
                for a in self.targets:
                    out.append({"train": tr, "test": te, "axis": a,
                                "rmse_um": float(self.rmse_um[a][i, j]),
                                "raw_rms_um": self.raw_rms_um.get(te, {}).get(a, math.nan),
                                "in_sample": bool(self.in_sample[i, j])})
        return out


def _none(v: float) -> float | None:
    return None if not math.isfinite(v) else round(float(v), 4)


def _nan_to_none(m: np.ndarray) -> list[list[float | None]]:
    return [[_none(v) for v in row] for row in np.asarray(m)]


def parse_runs(items: Sequence[str]) -> dict[str, list[str]]:
    """['constant=a.csv', 'step=b.csv', 'constant=c.csv'] -> {'constant': [a, c], 'step': [b]}."""
    out: dict[str, list[str]] = {}
    for item in items:
        name, sep, path = item.partition("=")
        if not sep or not name.strip() or not path.strip():
            raise ProtocolComparisonError(f"--runs item {item!r}: write NAME=RUN.csv "
                                          "(e.g. constant=day1.csv)")
        out.setdefault(name.strip(), []).append(path.strip())
    if len(out) < 2:
        raise ProtocolComparisonError("--runs: give runs of at least two protocols to compare")
    return out


def simulate_runs(out_dir: str | Path, protocols: Sequence[str] = PROTOCOLS, *,
                  max_rpm: float = 8000.0, hours: float = 8.0, cool_hours: float = 8.0,
                  dt_s: float = 60.0, n_sensors: int = 16, effects: Sequence[str] = (),
                  seed: int = 0, production: bool = True,
                  quiet: bool = True) -> dict[str, list[str]]:
    """A training and a test run of each protocol (different days) and a production day.

    Seeds: training run of protocol i uses seed + i, its test run seed + 100 + i, the
    production day (``random``, its own schedule) seed + 200. One machine (machine seed 0).
    """
    for p in protocols:
        if p not in PROTOCOLS:
            raise ProtocolComparisonError(f"unknown protocol '{p}' (known: "
                                          f"{', '.join(PROTOCOLS)})")
    out_dir = Path(out_dir)
    jobs = []
    for i, p in enumerate(protocols):
        jobs.append((p, p, seed + i, "train"))
        jobs.append((p, p, seed + 100 + i, "test"))
    if production:
        jobs.append((PRODUCTION, "random", seed + 200, "day"))
    runs: dict[str, list[str]] = {}
    for label, protocol, s, role in progress(jobs, "simulating runs", quiet=quiet):
        program = build_program(protocol, max_rpm, hours, cool_hours, seed=s)
        sim = simulate(program, SimConfig(n_sensors=n_sensors, dt_s=dt_s, seed=s,
                                          effects=tuple(effects)))
        path = out_dir / f"{label}_{role}_seed{s}.csv"
        write_simulation(sim, path)
        runs.setdefault(label, []).append(str(path))
    return runs


def compare_protocols(runs: Mapping[str, Sequence[str | Path]], targets: Sequence[str] = AXES,
                      *, sensors: str = "T*", aux: Sequence[str] | None = None,
                      max_sensors: int = 5, groups: int = 10, fit_effects: bool = False,
                      train_only: Sequence[str] | None = None, quiet: bool = True,
                      **train_kwargs) -> Comparison:
    """Train on the first run of each protocol, test on every other run of every label.

    ``runs`` maps a label (protocol, or ``production``) to its run paths, training run first.
    ``train_only`` limits the rows (default: every label except ``production``).
    """
    from thermal_comp.host.analysis.evaluate import evaluate_model
    from thermal_comp.host.train import train_model

    targets = list(targets)
    aux = list(aux or [])
    labels = list(runs)
    rows = [name for name in labels if name != PRODUCTION] if train_only is None else list(
        train_only)
    loaded = _load_protocols(runs, rows, targets, sensors, aux)
    test_cols: list[tuple[str, int]] = []  # (label, index of its run used for testing)
    for name in labels:
        test_cols.append((name, 1 if len(loaded[name]) > 1 and name in rows else 0))
    rmse = {a: np.full((len(rows), len(labels)), np.nan) for a in targets}
    in_sample = np.zeros((len(rows), len(labels)), bool)
    models: dict[str, dict] = {}
    pairs = [(i, j) for i in range(len(rows)) for j in range(len(labels))]
    model_cache: dict[int, dict] = {}
    for i, j in progress(pairs, "train x test", quiet=quiet):
        if i not in model_cache:
            train_run = loaded[rows[i]][0]
            model_cache[i] = train_model([train_run], targets, sensors=sensors, aux=aux,
                                         max_sensors=max_sensors, groups=groups,
                                         effects=fit_effects, quiet=True, fit="ols", nested=False,
                                         **train_kwargs)  # many trainings: no nested folds
            models[rows[i]] = _model_summary(train_run, model_cache[i])
        label, k = test_cols[j]
        test_run = loaded[label][k]
        in_sample[i, j] = test_run is loaded[rows[i]][0]
        result = evaluate_model(model_cache[i], test_run)
        for a in targets:
            rmse[a][i, j] = result["axes"][a]["rmse_um"]
    raw = {}
    for label, k in test_cols:
        r = loaded[label][k]
        raw[label] = {a: round(float(np.sqrt(np.mean(r.target(a) ** 2))), 4) for a in targets}
    return Comparison(rows, labels, targets, rmse, in_sample,
                      {n: [str(p) for p in ps] for n, ps in runs.items()}, models, raw,
                      {"sensors": sensors, "aux": aux, "max_sensors": max_sensors,
                       "groups": groups, "fit_effects": fit_effects})


def _load_protocols(runs: Mapping[str, Sequence[str | Path]], rows: Sequence[str],
                    targets: list[str], sensors: str, aux: list[str]) -> dict[str, list[Run]]:
    """Every label's runs loaded, after refusing a training protocol without runs; all must
    read one machine's sensors, or the matrix would compare machines, not protocols."""
    for name in rows:
        if name not in runs:
            raise ProtocolComparisonError(f"no runs for training protocol '{name}'")
    loaded: dict[str, list[Run]] = {
        name: [load_run(p, targets, sensors, aux, min_samples=4) for p in paths]
        for name, paths in runs.items()}
    first = next(iter(loaded.values()))[0]
    for rs in loaded.values():
        for r in rs:
            if r.sensor_names != first.sensor_names:
                raise ProtocolComparisonError(
                    f"{r.path}: temperature columns differ from {first.path}; protocols can "
                    "only be compared on one machine's sensors")
    return loaded


def _model_summary(train_run: Run, model: dict) -> dict:
    """What the matrix keeps of a row's model: its run, each axis's terms and validation."""
    return {
        "run": train_run.path,
        "axes": {a: [_term_label(t) for t in ax["terms"]]
                 for a, ax in model["axes"].items()},
        "validation_rmse_um": {a: round(ax["metrics"]["validation_rmse_um"], 4)
                               for a, ax in model["axes"].items()},
    }


def combine(comps: Sequence[Comparison]) -> Comparison:
    """Average several repeats (other days) of the same comparison; keeps each repeat's matrix.

    One day is one draw of noise, weather and random schedule: conclusions drawn from a single
    repeat can flip with the seed, the mean over repeats is what a protocol is worth.
    """
    if not comps:
        raise ProtocolComparisonError("nothing to combine")
    if len(comps) == 1:
        return comps[0]
    head = comps[0]
    for c in comps[1:]:
        if c.train != head.train or c.test != head.test or c.targets != head.targets:
            raise ProtocolComparisonError("repeats compare different protocols or axes")
    rmse = {a: np.mean([c.rmse_um[a] for c in comps], axis=0) for a in head.targets}
    raw = {t: {a: round(float(np.mean([c.raw_rms_um[t][a] for c in comps])), 4)
               for a in head.targets} for t in head.test}
    settings = dict(head.settings)
    settings["repeats"] = len(comps)
    settings["per_repeat_mean_rmse_um"] = [_nan_to_none(c.mean_rmse_um()) for c in comps]
    settings["per_repeat_ranking"] = [[n for n, _ in c.ranking()] for c in comps]
    settings["per_repeat_scores"] = [{n: _none(v) for n, v in c.ranking()} for c in comps]
    spread = np.std([c.mean_rmse_um() for c in comps], axis=0, ddof=1)
    settings["mean_rmse_sd_over_repeats_um"] = _nan_to_none(spread)
    runs = {k: [p for c in comps for p in c.runs[k]] for k in head.runs}
    models = {f"{k} (repeat {r + 1})": v for r, c in enumerate(comps) for k, v in c.models.items()}
    return Comparison(head.train, head.test, head.targets, rmse,
                      np.any([c.in_sample for c in comps], axis=0), runs, models, raw, settings)


def _term_label(t: dict) -> str:
    if t["kind"] == "temp":
        return t["source"]
    if t["kind"] in ("lag", "rate"):
        return f"{t['kind']}({t['source']},{t['tau_s']:g}s)"
    if t["kind"] == "square":
        return f"square({t['source']})"
    if t["kind"] in ("speed", "speed2"):
        return f"{t['kind']}({t['source']})"
    return t["kind"]


def format_matrix(comp: Comparison) -> str:
    """Plain-text matrices: one per axis and the mean over axes, rows = training protocol."""
    width = max(10, *(len(t) + 2 for t in comp.test))
    lines = []
    blocks = [(a, comp.rmse_um[a]) for a in comp.targets]
    if len(comp.targets) > 1:
        blocks.append(("mean of axes", comp.mean_rmse_um()))
    for title, m in blocks:
        lines.append(f"test RMSE (um), {title}: rows = trained on, columns = tested on")
        lines.append(f"{'':<12}" + "".join(f"{t:>{width}}" for t in comp.test))
        for i, tr in enumerate(comp.train):
            cells = []
            for j in range(len(comp.test)):
                mark = "*" if comp.in_sample[i, j] else " "
                cells.append(f"{m[i, j]:>{width - 1}.2f}{mark}")
            lines.append(f"{tr:<12}" + "".join(cells))
        lines.append("")
    if comp.in_sample.any():
        lines.append("* in-sample: the test run is the training run (give a second run of "
                     "that protocol to test on another day)")
    if comp.settings.get("repeats", 1) > 1:
        lines.append(f"each cell: mean over {comp.settings['repeats']} repeats (other days); "
                     "ranking per repeat: " + "; ".join(
                         ">".join(r) for r in comp.settings["per_repeat_ranking"]))
    verdict = comp.verdict()
    spread = verdict["spread_um"]
    lines.append("training protocols by mean RMSE on the other protocols' runs: " + ", ".join(
        f"{n} {v:.2f}" + (f" ± {spread[n]:.2f}" if spread.get(n) is not None else "") + " um"
        for n, v in comp.ranking() if math.isfinite(v)))
    lines.append(f"verdict: {verdict.get('reason', '')}")
    return "\n".join(lines)


def write_outputs(comp: Comparison, out_dir: str | Path) -> list[Path]:
    """protocols.csv (long table) and protocols.json (matrices), both atomically."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    csv_path = out_dir / "protocols.csv"
    tmp = csv_path.with_name(csv_path.name + ".tmp")
    with tmp.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=["train", "test", "axis", "rmse_um", "raw_rms_um",
                                           "in_sample"])
        w.writeheader()
        for row in comp.rows():
            w.writerow({**row, "rmse_um": f"{row['rmse_um']:.4f}",
                        "raw_rms_um": f"{row['raw_rms_um']:.4f}"})
    os.replace(tmp, csv_path)
    paths.append(csv_path)
    json_path = out_dir / "protocols.json"
    tmp = json_path.with_name(json_path.name + ".tmp")
    tmp.write_text(json.dumps(comp.to_json(), indent=2) + "\n")
    os.replace(tmp, json_path)
    paths.append(json_path)
    return paths


__all__ = ["AXES", "PRODUCTION", "RPM_COLUMN", "Comparison", "ProtocolComparisonError",
           "combine", "compare_protocols", "format_matrix", "parse_runs", "simulate_runs",
           "write_outputs"]

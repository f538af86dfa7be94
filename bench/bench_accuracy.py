"""Held-out accuracy: our model and its peers on runs none of them saw (issue 13).

Every column of a case is trained on the same training runs and scored on the same test run:
- ours: ``train_model`` defaults, ``effects=False`` and ``selection="paper"`` (with
  ``reference=`` when ``train_model`` takes it, and on both simulators dy declared the axis a
  column's bending moves, ``bending=``, as a user of a vertical machining center would:
  ``BENDING``), and "undeclared", the default without that declaration; predicted with
  ``host.analysis.evaluate.predict``;
- peers (scikit-learn, on the training runs only; internal CV on the training folds of
  ``host.fitting.fold_groups``): OLS on all sensors, the 4 sensors of largest |r| + OLS,
  forward SFS-4 / SFS-5 + OLS, LassoCV, exhaustive best 4 / 5 by training error (when the
  number of subsets is affordable), RidgeCV and LassoCV over the sensors plus first-order lags
  of every sensor (``LAG_TAUS_S``, computed causally from each run's start), and
  HistGradientBoostingRegressor on the temperatures.

Cases:
- ``sim``: the project's simulator (``host.sim``), machine seeds ``SIM_SEEDS`` with the lag,
  ambient and speed effects; train on a ``constant`` and a ``step`` day, test on a ``random``
  and a ``sine`` day that start at another hour and a warmer shop; dx/dy/dz; ``start``.
- ``sim_dev``: the independent simulator in ../shared/data/sim_dev (3 machines x every scenario:
  train on ``*_train_*``, test on each ``*_test_*``; the 64-sensor S0 too) and its S0
  leave-one-run-out (three days); dy/dz (dx is noise); ``start``.
- ``fl``: FL_THERMAL (../shared/data/fl_thermal/steps.csv), each 8 h cycle held out in turn,
  one probe per model (ch1..ch5) and all five probes on one box; ``none`` (one continuous
  recording, one fixed datum).
- ``fl_next``: FL_THERMAL forward in time, as a shop trains: the recording so far (cycles 1-2,
  then 1-3) as one run, the next cycle, faster and hotter, as the unseen day; the same
  variants; no target (issue 13's is on ``fl``), reported beside it.
- ``sim_other``: the project's simulator on other machines, ``OTHER_SIM_SEEDS``, built as
  ``sim`` is. The defaults were chosen on ``SIM_SEEDS`` (and on the other sources): these check
  that the choices hold on machines they were not chosen on; no target, reported beside.

Scoring is one function for every column (``score``): with ``start`` the test RMSE of
``referenced(prediction) - referenced(measured)``, with ``none`` the plain RMSE. ``referenced``
subtracts each run's start reference, the project's (host.fitting.reference): the running mean
of its first K samples (the box's ZERO window; causal: sample n uses the mean of samples
0..min(n, K-1)). Peers under ``start`` are fitted on
referenced features and targets of each training run (the same helper).

The best peer of a case is the one with the lowest test error, picked after seeing the test
run: no method can make that choice, so the bench also names the peer a user would pick
without it, the one with the lowest out-of-fold error on the training file (every peer
refitted, its own settings too, without each fold of ``fold_groups``; ``peer_validation``).

For sim_dev the bench also carries its manifest's scores of each test run (``floor_um``): the
oracle (least squares on the true node temperatures and effect term, what a model could at
best reach), the oracle without the hidden parts (the same on every measurable node and the
air: what perfect sensors everywhere could give, no unmeasured shaft, no effect term) and the
probe noise floor, as its README asks ("use the oracle as the floor"). The oracle without the
hidden parts is given per axis: it tells an axis whose sensors limit it from one near the floor.

Per case: every column's test RMSE (um), ours / best peer, ours / the peer picked by
validation, and the error ``host train`` promised (the axis's ``metrics.promised_rmse_um``,
before nested validation its ``validation_rmse_um``) against the test RMSE. Summary: geometric
mean of ours / best peer and of ours / the peer picked by validation per source, the loop's
effect (default worse than ``effects=False`` by more than 5 %), the calibration (promised
within a factor 2 of the test RMSE, and how many went worse or better than that), and the
timing target of ``host train`` on 64 x 86,400 rows. Writes bench/results/accuracy.json, its
figure bench/results/accuracy.png (bench.accuracy_figure) and the text table to stdout and
/tmp/accuracy_latest.txt; progress on stderr.

The bench's parts, one job each: the cases (bench.accuracy_jobs), the one score
(bench.accuracy_score), the peers (bench.accuracy_peers), the summary (bench.accuracy_summary)
and its text (bench.accuracy_table); this module trains ours, runs the jobs and writes the
results. Their names stay reachable here (``bench_accuracy.score``), as the other benches use
them.

    python -m bench accuracy                  # as part of the bench runner (also `make bench`)
    python -m bench.bench_accuracy --source fl --jobs 2   # one source, table only
"""

from __future__ import annotations

import argparse
import inspect
import json
import math
import os
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict
from pathlib import Path

import numpy as np

from bench.accuracy_cases import CALIBRATION_FACTOR, OURS, PEERS, RESULTS, ROOT, CaseResult
from bench.accuracy_jobs import (
    AUX,
    BENDING,
    BENDING_SOURCES,
    DEV_TARGETS,
    FL_CYCLE_S,
    FL_PROBES,
    FL_STEPS,
    OTHER_SIM_SEEDS,
    SHARED,
    SIM_DEV,
    SIM_EFFECTS,
    SIM_SEEDS,
    SIM_TARGETS,
    SOURCES,
    Job,
    RunSpec,
    declared_bending,
    dev_jobs,
    fl_jobs,
    fl_next_jobs,
    manifest_floor,
    sim_jobs,
)
from bench.accuracy_peers import (
    EXHAUSTIVE_LIMIT,
    HGB_MAX_ROWS,
    LAG_TAUS_S,
    PeerFit,
    Predictor,
    fit_peers,
    inner_folds,
    peer_features,
    peer_target,
    peer_validation,
    score_peers,
)
from bench.accuracy_score import (
    REF_WINDOW_S,
    Reference,
    causal_reference,
    reference_window,
    referenced,
    score,
)
from bench.accuracy_summary import (
    BOOTSTRAP_DRAWS,
    INTERVAL,
    LOOP_TOLERANCE,
    MIN_TRAINING_SETS,
    against_visible_oracle,
    clustered_interval,
    geomean,
    intervals,
    per_peer,
    summarise,
)
from bench.accuracy_table import (
    TARGET_SOURCES,
    interval_detail,
    interval_text,
    summary_rows,
    table,
)
from bench.goal import goal

__all__ = [  # the bench's face: its own names and those of its parts the other benches use
    "AUX", "BENDING", "BENDING_SOURCES", "BOOTSTRAP_DRAWS", "CALIBRATION_FACTOR", "DEV_TARGETS",
    "EXHAUSTIVE_LIMIT", "FL_CYCLE_S", "FL_PROBES", "FL_STEPS", "HGB_MAX_ROWS", "INTERVAL",
    "LAG_TAUS_S", "LATEST_TXT", "LOOP_TOLERANCE", "MIN_TRAINING_SETS", "OTHER_SIM_SEEDS",
    "OURS", "PEERS", "REF_WINDOW_S", "RESULTS", "ROOT", "SHARED", "SIM_DEV", "SIM_EFFECTS",
    "SIM_SEEDS", "SIM_TARGETS", "SOURCES", "TARGET_SOURCES", "CaseResult", "Job", "PeerFit",
    "Predictor", "Reference", "RunSpec", "against_visible_oracle", "causal_reference",
    "clustered_interval", "declared_bending", "dev_jobs", "evaluate", "fit_peers", "fl_jobs",
    "fl_next_jobs", "geomean", "highest_fold", "inner_folds", "interval_detail",
    "interval_text", "intervals", "jobs_for", "main", "manifest_floor", "ours_models",
    "peer_features", "peer_target", "peer_validation", "per_peer", "promised",
    "raw_prediction", "reference_window", "referenced", "run", "run_job", "score",
    "score_peers", "sim_jobs", "summarise", "summary_rows", "table", "train_kwargs",
    "train_timing_row",
]

LATEST_TXT = Path("/tmp/accuracy_latest.txt")


# --------------------------------------------------------------------------- ours

def _load(spec: RunSpec, targets: Sequence[str]):
    from thermal_comp.host.io import load_run, window

    run = load_run(spec.path, list(targets), "T*", AUX, min_samples=4)
    if spec.start_s is not None or spec.stop_s is not None:
        run = window(run, spec.start_s, spec.stop_s)
    return run


def train_kwargs(reference: str, bending: Sequence[str] = (),
                 targets: Sequence[str] = ()) -> dict:
    """``reference=`` for train_model when it takes it (issue 13), ``bending=`` (those of
    ``targets`` that bend) and ``jobs=`` (_worker_init) when it takes those; nothing before."""
    from thermal_comp.host.train import train_model

    params = inspect.signature(train_model).parameters
    out: dict = {"reference": reference} if "reference" in params else {}
    bent = [t for t in targets if t in bending]
    if bent and "bending" in params:
        out["bending"] = bent
    if _FOLD_JOBS is not None and "jobs" in params:
        out["jobs"] = _FOLD_JOBS
    return out


def promised(axis: dict) -> float:
    """The error ``host train`` promises for an axis on an unseen run: the nested out-of-fold
    RMSE (``metrics.promised_rmse_um``) where training reports one, else the validation RMSE."""
    m = axis["metrics"]
    return float(m.get("promised_rmse_um", m["validation_rmse_um"]))


def highest_fold(axis: dict) -> float:
    """The top of the promise's spread: the highest nested fold
    (``metrics.promised_fold_rmse_um``), NaN where training reports no folds."""
    folds = axis["metrics"].get("promised_fold_rmse_um") or []
    return float(max(folds)) if folds else math.nan


def raw_prediction(model: dict, run) -> dict[str, np.ndarray]:
    """The model's output before any reference (``score`` references it, as for the peers).

    host.analysis.evaluate.predict references a ``start`` model's output at the run's start;
    asked for ``none`` it returns the plain output, and referencing that is the same thing
    (the reference is linear). A predict without ``reference=`` returns the plain output.
    """
    from thermal_comp.host.analysis.evaluate import predict

    if "reference" in inspect.signature(predict).parameters:
        return predict(model, run, reference="none")
    return predict(model, run)



_FOLD_JOBS: int | None = None  # train_model(jobs=): 1 in a pool of several workers


def _worker_init(shared: bool = False) -> None:
    """One BLAS / OpenMP thread per worker process (the pool runs one worker per core), and
    with ``shared`` (several workers) the nested folds in the worker's own process: forked
    folds beside the other workers' jobs oversubscribe the cores (FL and fl_next: 261-273 s
    against 215-239 s with one process per worker, the same cases to the last digit).

    threadpoolctl limits only the libraries already loaded, so scikit-learn's OpenMP runtime
    is loaded first: with two OpenMP threads per worker on a busy machine, gradient boosting
    spins and takes 20x longer (80 s instead of 3 s for 600 x 25 rows, measured).
    """
    global _FOLD_JOBS
    import sklearn.ensemble  # noqa: F401  (loads the OpenMP runtime)
    from threadpoolctl import threadpool_limits

    threadpool_limits(1)
    _FOLD_JOBS = 1 if shared else None


def ours_models(job: Job, train: list, variant: str, column: str, nested: bool = True
                ) -> Iterator[tuple[list[str], dict, float]]:
    """Each model of our ``column`` (OURS) for one way of training on ``job``'s runs
    (``variant``, Job.ours_variants): (its targets, the model.json dict, seconds to train).
    ``nested=False`` skips nested validation, which gives the promise, not the model."""
    from thermal_comp.host.train import train_model

    per_target = dict(job.ours_variants())[variant]
    targets = list(job.targets)
    for group in ([[t] for t in targets] if per_target else [targets]):
        t0 = time.perf_counter()
        kwargs = train_kwargs(job.reference, () if column == "undeclared" else job.bending,
                              group) | OURS[column] | ({} if nested else {"nested": False})
        model = train_model(train, group, aux=AUX, **kwargs)
        yield group, model, time.perf_counter() - t0


def run_job(job: Job) -> tuple[list[dict], dict]:
    """Train every column of one job and score each (variant, test run, target)."""
    from thermal_comp.host.train import dropped_reason

    t_job = time.perf_counter()
    targets = list(job.targets)
    train = [_load(s, targets) for s in job.train]
    test = [(s, _load(s, targets)) for s in job.test]
    period = train[0].period_s
    cases = {(g, s.name, t): CaseResult(job.source, g, s.name, t, job.reference, job.group)
             for g, _ in job.ours_variants() for s, _ in test for t in targets}
    runs = {s.name: r for s, r in test}
    paths = {s.name: s.path for s, _ in test}
    for (_, name, t), case in cases.items():
        case.raw_um = score(runs[name].target(t), np.zeros(runs[name].n_samples),
                            job.reference, period)
        if job.source == "sim_dev":
            case.floor_um = manifest_floor(paths[name], t)
    timings: dict[str, float] = {}
    for variant, per_target in job.ours_variants():
        for column in OURS:
            if column == "undeclared" and not job.bending:
                for case in cases.values():  # the same model as the default's
                    for part in (case.rmse_um, case.promised_um, case.highest_fold_um,
                                 case.validation_um, case.n_terms, case.effects):
                        if "default" in part:
                            part[column] = part["default"]
                continue
            for group, model, seconds in ours_models(job, train, variant, column):
                key = f"train {column}" + (", per target" if per_target else "")
                timings[key] = timings.get(key, 0.0) + seconds
                for s, run in test:
                    pred = raw_prediction(model, run)
                    for t in group:
                        case = cases[(variant, s.name, t)]
                        axis = model["axes"][t]
                        case.rmse_um[column] = score(run.target(t), pred[t], job.reference,
                                                     period)
                        case.promised_um[column] = promised(axis)
                        case.highest_fold_um[column] = highest_fold(axis)
                        case.validation_um[column] = float(
                            axis["metrics"]["validation_rmse_um"])
                        case.n_terms[column] = len(axis["terms"])
                        case.effects[column] = [e["name"] for e in axis.get("effects", [])
                                                if not dropped_reason(e)]

    t0 = time.perf_counter()
    score_peers(job, train, test, cases)
    timings["peers"] = time.perf_counter() - t0
    timings["job"] = time.perf_counter() - t_job
    return [asdict(c) for c in cases.values()], {"group": job.group, **timings}



# --------------------------------------------------------------------------- the run

def train_timing_row() -> dict:
    """`host train` with defaults on 64 sensors x 86,400 rows in a fresh process (issue 2's
    target, measured the way bench_train does; repeated here so the table carries it)."""
    from bench.bench_train import synthetic_run, timed_process
    from thermal_comp.host.io import write_run

    with tempfile.TemporaryDirectory() as tmp:
        t, cols = synthetic_run(86_400, 64)
        csv = Path(tmp) / "run_86400.csv"
        write_run(csv, t, cols)
        timing = timed_process([sys.executable, "-m", "thermal_comp.host", "train", str(csv),
                                "--target",
                                "dz_um", "--out", str(Path(tmp) / "out"), "--json"])
    return {"name": "host train (defaults) 64 x 86,400 rows", "value": timing.fastest,
            "unit": "s", "target": "< 10 s on 2 cores", "goal": goal("<", 10),
            "detail": f"peak memory {timing.peak_mb:.0f} MB (process tree); "
                      f"{timing.describe()}, CSV parse + selection + effects + codegen "
                      "(bench/bench_train.py measures it too)"}


def _log(msg: str) -> None:
    print(f"[accuracy] {msg}", file=sys.stderr, flush=True)


def jobs_for(sources: Sequence[str], tmp: Path, big: bool = True) -> list[Job]:
    """Every job of the chosen sources, in a fixed order (the simulated runs written to
    ``tmp``, which must outlive the jobs)."""
    todo: list[Job] = []
    if "sim" in sources:
        _log("simulating the project's runs")
        todo += sim_jobs(tmp)
    if "sim_dev" in sources:
        todo += dev_jobs(big)
    if "fl" in sources:
        todo += fl_jobs()
    if "fl_next" in sources:
        todo += fl_next_jobs()
    if "sim_other" in sources:
        _log("simulating the project's other machines")
        todo += sim_jobs(tmp, OTHER_SIM_SEEDS, "sim_other")
    return todo


def evaluate(sources: Sequence[str] = SOURCES, jobs: int | None = None,
             big: bool = True) -> tuple[list[CaseResult], list[dict]]:
    """Run every job of the chosen sources (in parallel processes); cases in a fixed order."""
    with tempfile.TemporaryDirectory() as tmp:
        todo = jobs_for(sources, Path(tmp), big)
        n_workers = jobs or min(2, os.cpu_count() or 1)
        results: dict[int, tuple[list[dict], dict]] = {}
        # the 64-sensor jobs first: they are the longest
        order = sorted(range(len(todo)), key=lambda i: "S0_64" not in todo[i].group)
        t0 = time.perf_counter()
        with ProcessPoolExecutor(n_workers, initializer=_worker_init,
                                 initargs=(n_workers > 1,)) as pool:
            futures = {pool.submit(run_job, todo[i]): i for i in order}
            for n, fut in enumerate(as_completed(futures), 1):
                i = futures[fut]
                results[i] = fut.result()
                _log(f"{n}/{len(todo)} {todo[i].source} {todo[i].group} "
                     f"({results[i][1]['job']:.1f} s; {time.perf_counter() - t0:.0f} s so far)")
    cases = [CaseResult(**d) for i in range(len(todo)) for d in results[i][0]]
    return cases, [results[i][1] for i in range(len(todo))]


def _write(cases: list[CaseResult], summary: dict, timings: list[dict], extra: list[dict],
           text: str) -> None:
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps({
        "reference": {"start_samples_at_60s": reference_window(60.0),
                      "start_samples_at_15s": reference_window(15.0),
                      "project_reference": Reference is not None,
                      "train_model_reference_kw": bool(train_kwargs("start"))},
        "columns": {"ours": list(OURS), "peers": list(PEERS)},
        "bending": {source: list(declared_bending(source)) for source in SOURCES},
        "cases": [asdict(c) for c in cases], "summary": summary, "timings": timings,
        "rows": extra}, indent=1, allow_nan=True))
    try:
        LATEST_TXT.write_text(text + "\n")
    except OSError:
        pass
    from bench import accuracy_figure  # matplotlib only once the numbers are written

    _log(f"wrote {accuracy_figure.save(RESULTS, RESULTS.with_suffix('.png'))}")


def run() -> list[dict]:
    """The bench runner's entry: prints the table, writes the JSON; summary rows back."""
    cases, timings = evaluate()
    summary = summarise(cases)
    _log("timing host train on 64 x 86,400 rows")
    extra = [train_timing_row()]
    text = table(cases, summary, extra)
    print(text, flush=True)
    _write(cases, summary, timings, extra, text)
    return summary_rows(summary, len(cases)) + extra


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--source", action="append", choices=SOURCES,
                    help="only these sources (repeatable; default all)")
    ap.add_argument("--jobs", type=int, default=None, help="worker processes (default 2)")
    ap.add_argument("--no-64", action="store_true", help="skip the 64-sensor sim_dev case")
    ap.add_argument("--no-timing", action="store_true", help="skip the 64 x 86,400 timing")
    args = ap.parse_args(argv)
    cases, timings = evaluate(args.source or SOURCES, args.jobs,
                              not args.no_64)
    summary = summarise(cases)
    extra = [] if args.no_timing else [train_timing_row()]
    text = table(cases, summary, extra)
    print(text)
    _write(cases, summary, timings, extra, text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

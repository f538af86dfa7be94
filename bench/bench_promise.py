"""The promise's calibration (issue 43): what ``host train`` promises for an unseen day against
what the unseen day gave, per source, and the inflation that makes the promise keep its word.

``host train`` promises ``metrics.promised_rmse_um`` with a stated coverage ("RMS on an unseen
day <= X um on 80 % of days"; host.train.nested.PROMISE_COVERAGE). X is computed from the
nested folds' held-out errors (host.train.nested.promise_from_folds); the factor that
inflates them is fitted here. For every case of the accuracy bench's sources
(bench.bench_accuracy: sim, sim_dev, fl, fl_next, sim_other) this trains the default model
(nested validation on: the folds are what a promise can be built from), scores it on the
unseen run as that bench does, and keeps the chosen family's fold errors. The cases are saved
with their folds, so every candidate statistic is judged on the same training:

- each statistic of the folds (the lowest, the median, the RMS, the highest), scaled by the
  factor that the *other* sources need (leave-one-source-out: the smallest factor with at
  least ``COVERAGE`` of their cases at or below it and at most ``TAIL`` above twice it),
  judged on the source left out;
- the same factor fitted on every source, the one ``host train`` ships.

Per source: cases, fraction at or below the promise, fraction above twice it, and the median
promise / test (how pessimistic it is where it holds). Writes bench/results/promise.json (the
cases with their folds and the tables) and prints the tables.

    python -m bench promise                  # every source (about 7 min on 2 cores)
    python -m bench promise --quick          # the saved cases again, no training (seconds)
    python -m bench.bench_promise --update-cases   # train, and save the cases for --quick
    python -m bench.bench_promise --source fl_next --jobs 2   # train some sources only
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from bench import bench_accuracy as acc
from bench.goal import goal
from thermal_comp.host.train.nested import PROMISE_COVERAGE, PROMISE_TAIL

RESULTS = acc.ROOT / "bench" / "results" / "promise.json"
# the cases the promise (docs/training.md) was calibrated on (tracked; --quick reads them)
SAVED = acc.ROOT / "bench" / "data" / "promise_cases.json"
SOURCES = acc.SOURCES
# machines of the project's simulator no calibration (nor any earlier bench) saw: the test's
# held-out set (tests/host/train/test_promise.py; python -m bench.bench_promise --heldout)
HELDOUT_SEEDS = (15, 16, 17)
HELDOUT = acc.ROOT / "tests" / "data" / "promise_heldout.json"
RUNNER_FLAGS = ("--quick",)  # what ``python -m bench promise`` passes on to run()


@dataclass
class PromiseCase:
    """One unseen run and axis: the default model's test RMSE and its nested folds."""

    source: str
    group: str  # the way ours was trained (Job.ours_variants), as bench_accuracy's cases
    training_set: str  # the job: cases of one share their training data
    test: str
    target: str
    test_um: float
    folds_um: list[float]  # the chosen family's nested fold RMSEs (promised_fold_rmse_um)
    family: str
    scheme: str  # the nested folds' scheme (held-out runs or time blocks)


# --------------------------------------------------------------------------- training

def job_cases(job: acc.Job) -> list[dict]:
    """Every case of ``job``: the default model per variant, nested, scored on each test run."""
    targets = list(job.targets)
    train = [acc._load(s, targets) for s in job.train]
    test = [(s, acc._load(s, targets)) for s in job.test]
    period = train[0].period_s
    out = []
    for variant, _ in job.ours_variants():
        for group, model, _ in acc.ours_models(job, train, variant, "default"):
            for spec, run in test:
                pred = acc.raw_prediction(model, run)
                for t in group:
                    axis = model["axes"][t]
                    fit = axis.get("fit") or {}
                    out.append(asdict(PromiseCase(
                        job.source, variant, job.group, spec.name, t,
                        acc.score(run.target(t), pred[t], job.reference, period),
                        [float(v) for v in axis["metrics"].get("promised_fold_rmse_um") or []],
                        str(fit.get("family", "")),
                        str((fit.get("nested") or {}).get("scheme", "")))))
    return out


def collect(sources: Sequence[str], workers: int, big: bool = True,
            heldout: bool = False) -> list[PromiseCase]:
    """Every case of ``sources`` (jobs in parallel processes), in the bench's fixed order;
    with ``heldout`` the project simulator's machines ``HELDOUT_SEEDS`` instead."""
    with tempfile.TemporaryDirectory() as tmp:
        todo = (acc.sim_jobs(Path(tmp), HELDOUT_SEEDS, "sim_heldout") if heldout
                else acc.jobs_for(sources, Path(tmp), big))
        order = sorted(range(len(todo)), key=lambda i: "S0_64" not in todo[i].group)
        results: dict[int, list[dict]] = {}
        t0 = time.perf_counter()
        with ProcessPoolExecutor(workers, initializer=acc._worker_init,
                                 initargs=(workers > 1,)) as pool:
            futures = {pool.submit(job_cases, todo[i]): i for i in order}
            for n, fut in enumerate(as_completed(futures), 1):
                i = futures[fut]
                results[i] = fut.result()
                _log(f"{n}/{len(todo)} {todo[i].source} {todo[i].group} "
                     f"({time.perf_counter() - t0:.0f} s so far)")
    return [PromiseCase(**d) for i in range(len(todo)) for d in results[i]]


def _log(msg: str) -> None:
    print(f"[promise] {msg}", file=sys.stderr, flush=True)


def load(path: Path = SAVED) -> list[PromiseCase]:
    return [PromiseCase(**d) for d in json.loads(path.read_text())["cases"]]


# --------------------------------------------------------------------------- calibration

COVERAGE = PROMISE_COVERAGE  # at least this fraction of unseen days at or below the promise
TAIL = PROMISE_TAIL  # at most this fraction above twice it
BEFORE = "lowest"  # the promise until issue 43: the lowest fold, unscaled


def _rms(v: Sequence[float]) -> float:
    return float(np.sqrt(np.mean(np.square(v))))


# statistics of one case's nested fold RMSEs a promise can be scaled from
STATS: dict[str, Callable[[Sequence[float]], float]] = {
    "lowest": lambda v: float(np.min(v)), "median": lambda v: float(np.median(v)),
    "rms": _rms, "highest": lambda v: float(np.max(v)),
    "geometric mean": lambda v: float(np.exp(np.mean(np.log(v))))}


def usable(cases: Sequence[PromiseCase]) -> list[PromiseCase]:
    """The cases with folds and a finite test error (a model trained without nesting has
    none)."""
    return [c for c in cases if c.folds_um and math.isfinite(c.test_um)
            and all(math.isfinite(v) and v > 0 for v in c.folds_um)]


def needed_factor(ratios: Sequence[float], coverage: float = COVERAGE,
                  tail: float = TAIL) -> float:
    """The smallest factor k with at least ``coverage`` of ``ratios`` (test / statistic) at
    or below k and at most ``tail`` of them above 2k (NaN without ratios)."""
    r = np.sort(np.asarray(ratios, dtype=float))
    n = r.size
    if not n:
        return math.nan
    below = r[max(math.ceil(coverage * n - 1e-9), 1) - 1]  # the ceil(c n)-th smallest
    above = r[n - 1 - math.floor(tail * n + 1e-9)] / 2.0  # all but floor(t n) within 2k
    return float(max(below, above))


def ratios(cases: Sequence[PromiseCase], stat: str) -> list[float]:
    return [c.test_um / STATS[stat](c.folds_um) for c in cases]


def fitted_factor(cases: Sequence[PromiseCase], stat: str,
                  sources: Sequence[str] | None = None) -> float:
    """The factor that keeps the coverage on *every* one of ``sources`` (default: all of
    the cases'): the largest any of them needs on its own."""
    sources = list(sources if sources is not None else dict.fromkeys(c.source for c in cases))
    needs = [needed_factor(ratios([c for c in cases if c.source == s], stat)) for s in sources]
    needs = [k for k in needs if math.isfinite(k)]
    return max(needs) if needs else math.nan


def scaled(cases: Sequence[PromiseCase], stat: str, factor: float) -> list[float]:
    """Each case's promise: ``stat`` of its folds times ``factor``."""
    return [factor * STATS[stat](c.folds_um) for c in cases]


def coverage(cases: Sequence[PromiseCase], promised: Sequence[float]) -> dict:
    """How the ``promised`` values held on ``cases``: at or below them, above twice them, and
    the median test / promise."""
    r = np.array([c.test_um / p for c, p in zip(cases, promised, strict=True)], dtype=float)
    if not r.size:
        return {"cases": 0, "at or below": math.nan, "above twice": math.nan,
                "median test / promise": math.nan}
    return {"cases": int(r.size), "at or below": float(np.mean(r <= 1.0)),
            "above twice": float(np.mean(r > 2.0)),
            "median test / promise": float(np.median(r))}


def holds(cov: dict) -> bool:
    return cov["cases"] > 0 and cov["at or below"] >= COVERAGE - 1e-9 \
        and cov["above twice"] <= TAIL + 1e-9


def calibrate(cases: Sequence[PromiseCase]) -> dict:
    """Every statistic judged three ways, per source: as fitted on every source (the
    factor host train would ship), and left out (its factor fitted on the other sources)."""
    cases = usable(cases)
    sources = list(dict.fromkeys(c.source for c in cases))
    out: dict = {"coverage": COVERAGE, "tail": TAIL, "sources": sources,
                 "before": {s: coverage([c for c in cases if c.source == s],
                                        scaled([c for c in cases if c.source == s], BEFORE,
                                               1.0))
                            for s in sources},
                 "stats": {}}
    for stat in STATS:
        k_all = fitted_factor(cases, stat)
        per_source, left_out = {}, {}
        for s in sources:
            mine = [c for c in cases if c.source == s]
            per_source[s] = coverage(mine, scaled(mine, stat, k_all))
            k_rest = fitted_factor(cases, stat, [x for x in sources if x != s])
            left_out[s] = {"factor": k_rest,
                           **coverage(mine, scaled(mine, stat, k_rest))}
        out["stats"][stat] = {
            "factor": k_all,
            "needed per source": {s: needed_factor(ratios([c for c in cases if c.source == s],
                                                          stat)) for s in sources},
            "fitted on every source": per_source, "left out": left_out,
            "left out holds": sum(holds(v) for v in left_out.values()),
            # how pessimistic where it holds: geometric mean of promise / test, all cases
            "geomean promise / test": float(np.exp(np.mean(
                [math.log(k_all * STATS[stat](c.folds_um) / c.test_um) for c in cases]))),
        }
    return out


def held_out_text(cases: Sequence[PromiseCase]) -> str:
    """How host train's promise (nested.promise_from_folds) held on ``cases``."""
    from thermal_comp.host.train.nested import promise_from_folds

    cs = usable(cases)
    cov = coverage(cs, [promise_from_folds(c.folds_um) for c in cs])
    before = coverage(cs, scaled(cs, BEFORE, 1.0))
    return (f"{len(cs)} cases: at or below the promise {_pct(cov['at or below'])}, above "
            f"twice it {_pct(cov['above twice'])}, median test / promise "
            f"{cov['median test / promise']:.2f} (the lowest fold: {_pct(before['at or below'])}"
            f", {_pct(before['above twice'])}, {before['median test / promise']:.2f})")


def _pct(x: float) -> str:
    return f"{'-':>5}" if not math.isfinite(x) else f"{100 * x:4.0f}%"


def table(cal: dict) -> str:
    """The calibration per source: before (the lowest fold), and each statistic scaled."""
    sources = cal["sources"]
    lines = [f"The promise against the unseen run, per source: at or below it (target >= "
             f"{100 * cal['coverage']:.0f} %) / above twice it (target <= "
             f"{100 * cal['tail']:.0f} %) / median test / promise",
             f"{'promise':<44}" + "".join(f" {s:>22}" for s in sources)]

    def row(name: str, per: dict) -> str:
        return f"{name:<44}" + "".join(
            f" {per[s]['cases']:>3}: {_pct(per[s]['at or below'])} {_pct(per[s]['above twice'])}"
            f" {per[s]['median test / promise']:5.2f}" for s in sources)

    lines.append(row("before: the lowest fold", cal["before"]))
    for stat, v in cal["stats"].items():
        lines.append(row(f"{stat} x {v['factor']:.2f} (every source)",
                         v["fitted on every source"]))
        lines.append(row(f"{stat} x (the others' factor)", v["left out"])
                     + "   factors " + " ".join(f"{v['left out'][s]['factor']:.2f}"
                                                for s in sources)
                     + f"; holds left out on {v['left out holds']} of {len(sources)}")
    lines.append("the factor each source needs on its own: " + "; ".join(
        f"{stat} " + " ".join(f"{v['needed per source'][s]:.2f}" for s in sources)
        for stat, v in cal["stats"].items()))
    lines.append("geometric mean promise / test (fitted on every source): " + ", ".join(
        f"{stat} {v['geomean promise / test']:.2f}" for stat, v in cal["stats"].items()))
    shipped = cal.get("shipped")
    if shipped:
        lines.append(row(f"host train: {shipped['stat']} x {shipped['factor']:g}, >= median",
                         shipped["per source"]))
    return "\n".join(lines)


def shipped_coverage(cases: Sequence[PromiseCase]) -> dict[str, dict]:
    """Per source, how host train's promise (nested.promise_from_folds) held."""
    from thermal_comp.host.train.nested import promise_from_folds

    cs = usable(cases)
    out = {}
    for s in dict.fromkeys(c.source for c in cs):
        mine = [c for c in cs if c.source == s]
        out[s] = coverage(mine, [promise_from_folds(c.folds_um) for c in mine])
    return out


def report(cases: Sequence[PromiseCase], out: Path) -> dict:
    """Calibrate, print the table and write ``out``; the calibration back."""
    from thermal_comp.host.train import nested

    cal = calibrate(cases)
    cal["shipped"] = {"stat": "geometric mean", "factor": nested.PROMISE_FACTOR,
                      "per source": shipped_coverage(cases)}
    print(table(cal), flush=True)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"calibration": cal, "cases": [asdict(c) for c in cases]},
                              indent=1))
    _log(f"wrote {out}")
    return cal


def run(flags: Sequence[str] = ()) -> list[dict]:
    """The bench runner's entry (``--quick``: the saved cases, no training): per source, the
    share of unseen runs at or below host train's promise and above twice it."""
    quick = "--quick" in flags
    cases = load(SAVED) if quick else collect(SOURCES, min(2, os.cpu_count() or 1))
    cal = report(cases, RESULTS)
    rows = []
    for s, v in cal["shipped"]["per source"].items():
        rows.append({"name": f"{s}: unseen runs at or below the promise",
                     "value": v["at or below"], "unit": "fraction",
                     "target": f">= {COVERAGE}", "goal": goal(">=", COVERAGE),
                     "detail": f"{v['cases']} cases"})
        rows.append({"name": f"{s}: unseen runs above twice the promise",
                     "value": v["above twice"], "unit": "fraction", "target": f"<= {TAIL}",
                     "goal": goal("<=", TAIL),
                     "detail": f"median test / promise {v['median test / promise']:.2f}"})
    return rows


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true",
                    help=f"no training: the cases saved in {SAVED.relative_to(acc.ROOT)} again")
    ap.add_argument("--update-cases", action="store_true",
                    help=f"train, then save the cases to {SAVED.relative_to(acc.ROOT)}")
    ap.add_argument("--source", action="append", choices=SOURCES,
                    help="train only these sources (repeatable; default all)")
    ap.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1),
                    help="worker processes (default 2)")
    ap.add_argument("--no-64", action="store_true", help="skip the 64-sensor sim_dev cases")
    ap.add_argument("--heldout", action="store_true",
                    help=f"train the held-out machines {HELDOUT_SEEDS} only and write "
                    f"{HELDOUT.relative_to(acc.ROOT)} (the test's cases)")
    ap.add_argument("-o", "--out", type=Path, default=None, help="the JSON written")
    args = ap.parse_args(argv)
    if args.heldout:
        cases = collect((), args.jobs, heldout=True)
        out = args.out or HELDOUT
        out.write_text(json.dumps({"about": f"bench.bench_promise --heldout: the project "
                                   f"simulator's machines {HELDOUT_SEEDS}, trained as the "
                                   "accuracy bench's sim jobs; no calibration used them",
                                   "cases": [asdict(c) for c in cases]}, indent=1))
        print(held_out_text(cases))
        _log(f"wrote {out}")
        return 0
    cases = load(SAVED) if args.quick else collect(args.source or SOURCES, args.jobs,
                                                   not args.no_64)
    report(cases, args.out or RESULTS)
    if args.update_cases and not args.quick:
        SAVED.write_text(json.dumps({"about": "bench.bench_promise's cases (--update-cases)",
                                     "cases": [asdict(c) for c in cases]}, indent=1))
        _log(f"wrote {SAVED}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""One column of ours against a saved accuracy bench: a change to the fit judged in minutes.

The accuracy bench (``python -m bench accuracy``) trains five columns of ours and ten peers on
every case, with nested validation: 12-24 min on 2 cores. A change to how the box's model is
fitted moves one column, and nested validation gives the error ``host train`` promises, not
the model. So this trains that column alone (``nested=False``) on the bench's own jobs, scores
it as the bench does, and takes every peer from a saved bench JSON. The output is a bench
JSON holding that column and the saved peers, read by ``bench.compare_accuracy`` (printed
here too): after / before per source with its interval, the cases moved by more than 5 %,
and ours / best peer before and after. Run on an unchanged tree, every ratio is 1.000: the
check that the saved bench and the code still agree.

Without a saved bench it compares against the one the repository ships,
bench/data/accuracy_baseline.json: the peers and our default column (trained as here) on
every case, from the commit it names, so a fresh clone needs no 15-minute bench first.
``--write-baseline`` computes that file again (our column and the ten peers on every job,
without nested validation: a few minutes on 2 cores); where it is missing, it is computed
first, and the run says so.

The variants in docs/lab/next-day.md were measured this way (at first each with a
prototype rebuilt by hand).

    python -m bench.quick_accuracy                 # against the shipped baseline
    # ... change host/ ...
    python -m bench.quick_accuracy -o /tmp/variant.json
    python -m bench.quick_accuracy bench/results/accuracy.json   # against your own bench
    python -m bench.quick_accuracy SAVED.json --source fl --column "no effects"
    python -m bench.quick_accuracy --write-baseline  # after a change the baseline should keep
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, replace
from pathlib import Path

from bench import bench_accuracy as acc
from bench import compare_accuracy as cmp

DEFAULT_OUT = Path("/tmp/accuracy_quick.json")
BASELINE = Path(__file__).parent / "data" / "accuracy_baseline.json"

Key = cmp.Key


def scored(job: acc.Job, column: str) -> list[tuple[Key, float]]:
    """Our ``column``'s test error on every case of ``job`` (the bench's score)."""
    targets = list(job.targets)
    train = [acc._load(s, targets) for s in job.train]
    test = [(s, acc._load(s, targets)) for s in job.test]
    period = train[0].period_s
    out = []
    for variant, _ in job.ours_variants():
        for group, model, _ in acc.ours_models(job, train, variant, column, nested=False):
            for spec, run in test:
                pred = acc.raw_prediction(model, run)
                out += [((job.source, variant, spec.name, t),
                         acc.score(run.target(t), pred[t], job.reference, period))
                        for t in group]
    return out


def merged(saved: dict[Key, acc.CaseResult], errors: dict[Key, float], column: str
           ) -> list[acc.CaseResult]:
    """The saved cases with ``column`` replaced by ``errors`` and our other columns (and the
    promises, trained with nested validation) dropped: only the peers are carried over."""
    missing = sorted(k for k in errors if k not in saved)
    if missing:
        raise SystemExit(f"{len(missing)} cases are not in the saved bench, e.g. "
                         f"{' / '.join(missing[0])}: save one from this version "
                         "(python -m bench accuracy)")
    out = []
    for key, err in errors.items():
        c = saved[key]
        peers = {p: v for p, v in c.rmse_um.items() if p in acc.PEERS}
        out.append(replace(c, rmse_um=peers | {column: err}, promised_um={},
                           highest_fold_um={}, validation_um={}, n_terms={}, effects={}))
    return out


def moved_most(before: dict[Key, acc.CaseResult], after: dict[Key, acc.CaseResult],
               column: str, n: int = 8) -> str:
    """The ``n`` cases whose ``column`` moved most (by ratio), either way."""
    moved = []
    for key, c in after.items():
        b, a = before[key].rmse_um.get(column, math.nan), c.rmse_um[column]
        if b > 0 and a > 0 and math.isfinite(a + b) and a != b:
            moved.append((abs(math.log(a / b)), key, b, a))
    moved.sort(reverse=True)
    if not moved:
        return f"no case's {column} moved"
    lines = [f"the {min(n, len(moved))} cases moved most ({column}, um):"]
    lines += [f"  {' / '.join(k)}: {b:.3f} -> {a:.3f}" for _, k, b, a in moved[:n]]
    return "\n".join(lines)


def run(saved: dict[Key, acc.CaseResult], sources: Sequence[str], column: str, workers: int
        ) -> list[acc.CaseResult]:
    """``column`` trained on every job of ``sources``, merged with the ``saved`` peers."""
    with tempfile.TemporaryDirectory() as tmp:
        todo = acc.jobs_for(sources, Path(tmp))
        order = sorted(todo, key=lambda j: "S0_64" not in j.group)  # the longest first
        errors: dict[Key, float] = {}
        t0 = time.perf_counter()
        with ProcessPoolExecutor(workers, initializer=acc._worker_init,
                                 initargs=(workers > 1,)) as pool:
            futures = {pool.submit(scored, job, column): job for job in order}
            for n, fut in enumerate(as_completed(futures), 1):
                errors.update(fut.result())
                job = futures[fut]
                acc._log(f"{n}/{len(todo)} {job.source} {job.group} "
                         f"({time.perf_counter() - t0:.0f} s so far)")
    return merged(saved, errors, column)


def baseline_job(job: acc.Job, column: str) -> list[dict]:
    """Every case of ``job`` with our ``column`` (as ``scored`` trains it) and every peer."""
    targets = list(job.targets)
    train = [acc._load(s, targets) for s in job.train]
    test = [(s, acc._load(s, targets)) for s in job.test]
    cases = {(g, s.name, t): acc.CaseResult(job.source, g, s.name, t, job.reference, job.group)
             for g, _ in job.ours_variants() for s, _ in test for t in targets}
    for (_, group, name, t), err in scored(job, column):
        cases[(group, name, t)].rmse_um[column] = err
    acc.score_peers(job, train, test, cases)
    return [asdict(c) for c in cases.values()]


def _commit() -> str:
    done = subprocess.run(["git", "describe", "--always", "--dirty"], capture_output=True,
                          text=True, cwd=Path(__file__).parent)
    return done.stdout.strip() if done.returncode == 0 else "unknown"


def write_baseline(out: Path, column: str, workers: int) -> Path:
    """The shipped baseline: our ``column`` and the peers on every job of every source."""
    cases: list[dict] = []
    with tempfile.TemporaryDirectory() as tmp:
        todo = acc.jobs_for(acc.SOURCES, Path(tmp))
        order = sorted(todo, key=lambda j: "S0_64" not in j.group)  # the longest first
        t0 = time.perf_counter()
        with ProcessPoolExecutor(workers, initializer=acc._worker_init,
                                 initargs=(workers > 1,)) as pool:
            futures = {pool.submit(baseline_job, job, column): job for job in order}
            for n, fut in enumerate(as_completed(futures), 1):
                cases += fut.result()
                acc._log(f"baseline {n}/{len(todo)} {futures[fut].source} "
                         f"{futures[fut].group} ({time.perf_counter() - t0:.0f} s so far)")
    cases.sort(key=lambda c: (acc.SOURCES.index(c["source"]), c["group"], c["test"],
                              c["target"]))
    about = (f"bench.quick_accuracy --write-baseline at {_commit()}: our {column!r} column "
             "(no nested validation) and the peers on every case of the accuracy bench; what "
             "`python -m bench.quick_accuracy` compares against by default")
    write_cases(out, about, column, cases)
    return out


KEPT = ("source", "group", "test", "target", "reference", "training_set", "rmse_um", "raw_um")


def write_cases(out: Path, about: str, column: str, cases: list[dict]) -> None:
    """The baseline file: what the comparison reads of each case, one case a line."""
    lines = [json.dumps({k: c[k] for k in KEPT if k in c}, allow_nan=True) for c in cases]
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(f'{{"about": {json.dumps(about)},\n "column": {json.dumps(column)},\n'
                   ' "cases": [\n' + ",\n".join(lines) + "\n]}\n")


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("saved", type=Path, nargs="?", default=None,
                    help="an accuracy bench's JSON (its peers are reused; default: the "
                    f"shipped baseline, {BASELINE.relative_to(acc.ROOT)})")
    ap.add_argument("--write-baseline", action="store_true",
                    help=f"compute {BASELINE.relative_to(acc.ROOT)} again (every source) "
                    "and stop")
    ap.add_argument("--source", action="append", choices=acc.SOURCES,
                    help="only these sources (repeatable; default all)")
    ap.add_argument("--column", default="default",
                    choices=list(acc.OURS),
                    help="which of ours to train (default: default)")
    ap.add_argument("--jobs", type=int, default=2, help="worker processes (default 2)")
    ap.add_argument("-o", "--out", type=Path, default=DEFAULT_OUT,
                    help=f"the JSON written (default {DEFAULT_OUT})")
    args = ap.parse_args(argv)
    if args.jobs < 1:
        ap.error("--jobs must be at least 1")
    if args.write_baseline:
        print(f"wrote {write_baseline(BASELINE, args.column, args.jobs)}", file=sys.stderr)
        return 0
    if args.saved is None:
        if not BASELINE.exists():
            acc._log(f"no {BASELINE}: computing it first (every source, a few minutes)")
            write_baseline(BASELINE, "default", args.jobs)
        args.saved = BASELINE
        about = json.loads(BASELINE.read_text()).get("about", "")
        acc._log(f"against the shipped baseline {BASELINE.relative_to(acc.ROOT)} ({about})")
    saved = cmp.load(args.saved)  # before the work: a wrong file fails at once
    cases = run(saved, args.source or acc.SOURCES, args.column, args.jobs)
    args.out.write_text(json.dumps({"quick": {"saved": str(args.saved), "column": args.column},
                                    "cases": [asdict(c) for c in cases]}, indent=1))
    after = {(c.source, c.group, c.test, c.target): c for c in cases}
    print(cmp.table(cmp.compare(saved, after, args.column), args.column, None))
    print(moved_most(saved, after, args.column))
    print(f"wrote {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Two accuracy benches side by side: did a change move the unseen-run error, beyond the noise?

A change to the model is judged case by case on the runs it never saw: per source, the
geometric mean of after / before over the cases both benches hold, its 90 % interval with
whole training sets resampled (``bench_accuracy.clustered_interval``: the cases of one
training set share its models), how many cases moved by more than 5 % each way, and the
target's ratio (ours / best peer) before and after. A gain whose interval straddles 1 is not
shown by these cases. ``--plot`` draws every case's error before against after, log-log.

    python -m bench.compare_accuracy before.json after.json             # the default column
    python -m bench.compare_accuracy a.json b.json --column "no effects" --plot cmp.png
    python -m bench.compare_accuracy acc.json acc.json --column default --against paper
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from matplotlib.figure import Figure

from bench.accuracy_figure import COLOURS
from bench.accuracy_figure import SOURCES as NAMES  # matplotlib's Agg backend set there
from bench.bench_accuracy import (
    INTERVAL,
    LOOP_TOLERANCE,
    SOURCES,
    CaseResult,
    clustered_interval,
    geomean,
)

Key = tuple[str, str, str, str]


@dataclass
class Moved:
    """One source's paired comparison."""
    source: str
    cases: int
    training_sets: int
    geomean: float  # after / before
    interval: tuple[float, float]
    worse: int  # after above before by more than LOOP_TOLERANCE
    better: int
    target_before: float  # geometric mean of ours / best peer
    target_after: float


def load(path: Path) -> dict[Key, CaseResult]:
    """A bench's cases by (source, group, test run, target); a clear error if it is none."""
    try:
        doc = json.loads(path.read_text())
        cases = [CaseResult(**d) for d in doc["cases"]]
    except FileNotFoundError:
        raise SystemExit(f"{path}: no such file (run `python -m bench accuracy`)") from None
    except (json.JSONDecodeError, KeyError, TypeError) as e:
        raise SystemExit(f"{path}: not an accuracy bench's JSON ({e})") from None
    return {(c.source, c.group, c.test, c.target): c for c in cases}


def compare(before: dict[Key, CaseResult], after: dict[Key, CaseResult],
            column: str = "default", against: str | None = None) -> list[Moved]:
    """Per source, ``after``'s ``column`` over ``before``'s ``against`` (the same column by
    default) on the cases both hold and both scored."""
    against = against or column
    pairs = {k: (before[k].rmse_um.get(against, math.nan), a.rmse_um.get(column, math.nan))
             for k, a in after.items() if k in before}
    pairs = {k: (b, a) for k, (b, a) in pairs.items()
             if b > 0 and a > 0 and math.isfinite(a) and math.isfinite(b)}
    out = []
    for source in [s for s in SOURCES if any(k[0] == s for k in pairs)]:
        keys = [k for k in pairs if k[0] == source]
        cs = [after[k] for k in keys]
        ratio = {id(after[k]): pairs[k][1] / pairs[k][0] for k in keys}
        out.append(Moved(
            source, len(keys), len({c.cluster for c in cs}),
            geomean(list(ratio.values())),
            clustered_interval(cs, lambda c, r=ratio: r[id(c)]),
            sum(r > LOOP_TOLERANCE for r in ratio.values()),
            sum(r < 1 / LOOP_TOLERANCE for r in ratio.values()),
            geomean([pairs[k][0] / before[k].best_peer[1] for k in keys]),
            geomean([pairs[k][1] / after[k].best_peer[1] for k in keys])))
    return out


def table(moved: Sequence[Moved], column: str, against: str | None) -> str:
    what = f"{column} / {against or column}"
    tol = f"{100 * (LOOP_TOLERANCE - 1):.0f} %"
    lines = [f"after / before ({what}), geometric mean with its {100 * INTERVAL:.0f} % "
             "interval over whole training sets",
             f"{'source':<10} {'cases':>5} {'sets':>4} {'after/before':>12} {'interval':>13} "
             f"{'worse>' + tol:>9} {'better>' + tol:>10} {'ours/best peer':>18}"]
    for m in moved:
        lo, hi = m.interval
        iv = f"{lo:.3f}-{hi:.3f}" if math.isfinite(lo) else "none (< 3)"
        lines.append(f"{m.source:<10} {m.cases:>5} {m.training_sets:>4} {m.geomean:>12.3f} "
                     f"{iv:>13} {m.worse:>9} {m.better:>10} "
                     f"{m.target_before:>8.3f} -> {m.target_after:.3f}")
    return "\n".join(lines)


def plot(before: dict[Key, CaseResult], after: dict[Key, CaseResult], column: str,
         against: str | None, out: Path) -> Path:
    """Every case's test error before against after, log-log, one colour per source."""
    fig = Figure(figsize=(6.4, 6.0))
    ax = fig.add_subplot()
    lo, hi = math.inf, 0.0
    for source in SOURCES:
        xy = [(b.rmse_um.get(against or column, math.nan), after[k].rmse_um.get(column, math.nan))
              for k, b in before.items() if k[0] == source and k in after]
        xy = [(x, y) for x, y in xy if x > 0 and y > 0 and math.isfinite(x + y)]
        if not xy:
            continue
        x, y = zip(*xy, strict=True)
        ax.scatter(x, y, s=14, alpha=0.7, color=COLOURS[source],
                   label=f"{NAMES[source]} ({len(xy)})")
        lo, hi = min(lo, *x, *y), max(hi, *x, *y)
    if hi == 0:
        raise SystemExit("no case both benches scored: nothing to plot")
    ax.plot([lo, hi], [lo, hi], "k-", lw=0.8)
    for f in (LOOP_TOLERANCE, 1 / LOOP_TOLERANCE):
        ax.plot([lo, hi], [lo * f, hi * f], "k:", lw=0.6)
    ax.set(xscale="log", yscale="log", xlabel=f"before: {against or column}, test RMSE (µm)",
           ylabel=f"after: {column}, test RMSE (µm)",
           title="Unseen-run error per case (below the diagonal: better)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("before", type=Path, help="an accuracy bench's JSON")
    ap.add_argument("after", type=Path, help="another (or the same, with --against)")
    ap.add_argument("--column", default="default", help="after's column (default: default)")
    ap.add_argument("--against", default=None, help="before's column (default: --column)")
    ap.add_argument("--plot", type=Path, default=None, help="write the per-case figure here")
    args = ap.parse_args(argv)
    before, after = load(args.before), load(args.after)
    moved = compare(before, after, args.column, args.against)
    if not moved:
        ap.error(f"no case of {args.after} has a match in {args.before} with both columns "
                 "scored")
    unmatched = sum(k not in before for k in after) + sum(k not in after for k in before)
    print(table(moved, args.column, args.against))
    if unmatched:
        print(f"({unmatched} cases in only one of the two benches, left out)")
    if args.plot:
        print(f"wrote {plot(before, after, args.column, args.against, args.plot)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

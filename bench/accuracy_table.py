"""The accuracy bench's text: the table of every case with the summary beneath it (stdout and
/tmp/accuracy_latest.txt), and the bench runner's rows (its table and bench.json)."""

from __future__ import annotations

import math
from collections.abc import Sequence

from bench.accuracy_cases import OURS, PEERS, CaseResult
from bench.accuracy_jobs import BENDING, BENDING_SOURCES
from bench.accuracy_summary import INTERVAL, LOOP_TOLERANCE
from bench.goal import INFO, goal
from thermal_comp.contract.box import BOX_CHANNELS

TARGET_SOURCES = ("sim_dev", "fl")  # issue 13's <= 0.8 (FL: its cycles held out in turn)
SHORT = {"default": "deflt", "no effects": "noeff", "paper": "paper", "undeclared": "undcl",
         "no prefilter": "nopre", "OLS all": "OLS",
         "top-4 |r|": "top4", "SFS-4": "SFS4", "SFS-5": "SFS5", "LassoCV": "Lasso",
         "best-4": "best4", "best-5": "best5", "ridge+lags": "ridgeL",
         "lasso+lags": "lassoL", "HGB": "HGB"}  # the columns' headings, six characters


def interval_text(iv: dict) -> str:
    """One line: each ratio of ``intervals`` with its interval over the training sets."""
    def one(name: str) -> str:
        lo, hi = iv[name]["interval"]
        span = f" ({lo:.3f}-{hi:.3f})" if math.isfinite(lo) else " (no interval)"
        return f"{name} {iv[name]['geomean']:.3f}{span}"
    return (f"{100 * INTERVAL:.0f} % intervals, whole training sets resampled "
            f"({iv['training sets']} of them): "
            + "; ".join(one(n) for n in ("default / best peer", "default / no effects",
                                         "default / paper")))


def _f(x: float, width: int = 6) -> str:
    return f"{'-':>{width}}" if not math.isfinite(x) else f"{x:{width}.2f}"


def table(cases: list[CaseResult], summary: dict, extra_rows: Sequence[dict] = ()) -> str:
    """Every case's columns, then per source the summary, the loop, the calibration and the
    ``extra_rows`` (the timing of host train)."""
    lines = [*header(), *case_lines(cases), *summary_lines(summary),
             *loop_lines(summary["loop_worse"], len(cases)),
             *calibration_lines(summary["calibration"])]
    for r in extra_rows:
        lines.append(f"  {r['name']}: {r['value']:.3g} {r['unit']} (target {r.get('target', '')})"
                     f" {r.get('detail', '')}")
    return "\n".join(lines)


def header() -> list[str]:
    """The legend of the columns, their headings and the rule beneath."""
    cols = [*OURS, *PEERS]
    head = (f"{'case':<42} {'axis':<6} {'ref':<5} {'raw':>6} "
            + " ".join(f"{SHORT[c]:>6}" for c in cols)
            + f" {'best peer':<11} {'d/peer':>6} {'d/box':>6} {'val. peer':<11} {'d/val':>6}"
            f" {'promis':>6} {'t/prom':>6}")
    return ["Held-out test RMSE (um); ours = deflt/noeff/paper/undcl/nopre (undcl: the "
            "default without the bending declaration; nopre: without the ridge's prefilter); "
            "raw = no compensation; "
            "d/peer = default / best peer, d/box = default / best peer with <= "
            f"{BOX_CHANNELS} sensors, val. peer = the peer with the lowest out-of-fold error "
            "on the training file, d/val = default / it; "
            "promis = default's metrics.promised_rmse_um (else "
            "validation_rmse_um), "
            f"t/prom = test / promised; ours on {' and '.join(BENDING_SOURCES)} with "
            f"{', '.join(BENDING)} declared a bending axis (train_model(bending=))",
            head, "-" * len(head)]


def case_lines(cases: list[CaseResult]) -> list[str]:
    """One line per case under its source: raw, every column, the best and the validated
    peer with ours against each, the promise and test / promised."""
    cols = [*OURS, *PEERS]
    lines: list[str] = []
    source = None
    for c in cases:
        if c.source != source:
            source = c.source
            lines.append(f"[{source}]")
        name, best, val = f"{c.group}: {c.test}", c.best_peer, c.validated_peer
        prom = c.promised_um.get("default", math.nan)
        lines.append(f"{name[:42]:<42} {c.target.removesuffix('_um'):<6} {c.reference:<5} "
                     f"{_f(c.raw_um)} "
                     + " ".join(_f(c.rmse_um.get(col, math.nan)) for col in cols)
                     + f" {best[0]:<11} {_f(c.ratio())} {_f(c.box_ratio())} {val[0]:<11} "
                     f"{_f(c.validated_ratio())} {_f(prom)} "
                     f"{_f(c.rmse_um['default'] / prom if prom > 0 else math.nan)}")
    return lines


def summary_lines(summary: dict) -> list[str]:
    """Per source: ours against the best peer, the intervals, the peers that won, the peer
    picked by validation, each peer on its own and the oracle floors."""
    lines: list[str] = []
    lines.append("")
    lines.append("Summary (geometric mean of ours / best peer per case; target <= 0.8 on "
                 "sim_dev and FL)")
    for source, s in summary["per_source"].items():
        lines.append(f"  {source:<8} {s['cases']:>3} cases: "
                     + ", ".join(f"{col} {s[f'geomean {col} / best peer']:.3f}" for col in OURS)
                     + f"; default within 1.1x of best peer in "
                     f"{s['default within 1.1x of best peer']}, beats it in "
                     f"{s['default beats best peer']}; default / best peer the box can run "
                     f"(<= {BOX_CHANNELS} sensors) "
                     f"{s['geomean default / best peer within the box']:.3f}")
        lines.append("           " + interval_text(s["intervals"]))
        lines.append("           best peer: " + ", ".join(
            f"{p} {n}" for p, n in s["best peer counts"].items() if n))
        lines.append("           ours / the peer picked by validation on the training file: "
                     + ", ".join(f"{col} {s[f'geomean {col} / peer picked by validation']:.3f}"
                                 for col in OURS)
                     + "; picked: " + ", ".join(
                         f"{p} {n}" for p, n in s["peer picked by validation counts"].items()
                         if n))
        lines.append("           ours / each peer on its own: " + ", ".join(
            f"{p} {v:.3f}" for p, v in s["geomean default / each peer"].items()
            if math.isfinite(v)))
        lines.append(f"           the strongest single peer, {s['strongest single peer']}, is "
                     f"{s['geomean strongest single peer / best peer']:.3f}x the best per "
                     f"case; ours / it {s['geomean default / strongest single peer']:.3f}")
        if "geomean default / oracle" in s:
            lines.append(f"           against the manifest's oracle (the floor, on "
                         f"{s['cases with an oracle']} cases): default "
                         f"{s['geomean default / oracle']:.2f}x, best peer "
                         f"{s['geomean best peer / oracle']:.2f}x; the oracle is "
                         f"{s['geomean oracle / noise floor']:.2f}x the probe noise floor")
        for target, v in s.get("against the oracle without hidden parts", {}).items():
            lines.append(f"           {target} against the oracle without hidden parts "
                         f"(perfect sensors on every measurable node, {v['cases']} cases): "
                         f"default {v['geomean default / it']:.2f}x, best peer "
                         f"{v['geomean best peer / it']:.2f}x; it is "
                         f"{v['geomean it / noise floor']:.2f}x the probe noise floor")
    return lines


def loop_lines(worse: list[dict], n_cases: int) -> list[str]:
    """The cases where the loop (effects) made the default worse than effects=False."""
    lines: list[str] = []
    lines.append(f"The loop (default vs effects=False): worse by more than "
                 f"{100 * (LOOP_TOLERANCE - 1):.0f} % in {len(worse)} of {n_cases} cases")
    for w in worse:
        lines.append(f"  {w['source']} {w['group']}: {w['test']} {w['target']}: "
                     f"{w['no_effects_um']:.2f} -> {w['default_um']:.2f} um; effects: "
                     f"{', '.join(w['effects']) or 'none kept'}")
    return lines


def calibration_lines(calibration: dict) -> list[str]:
    """Per source: the promise's coverage, then how often the test fell within a factor 2."""
    lines: list[str] = []
    lines.append("Calibration (default: test RMSE / the RMSE host train promised; the "
                 "promise states 80 % at or below it, bench.bench_promise)")
    lines.append(f"  {'source':<10} {'cases':>5} {'<= promise':>10} {'> 2x promise':>12}")
    for source, s in calibration.items():
        lines.append(f"  {source:<10} {s['cases']:>5} "
                     f"{100 * s.get('fraction at or below the promise', math.nan):>9.0f}% "
                     f"{100 * s.get('fraction above twice the promise', math.nan):>11.0f}%")
    for source, s in calibration.items():
        lines.append(f"  {source:<8} within a factor 2 in {s['within factor 2']} of "
                     f"{s['cases']} (the test worse by more than 2x in "
                     f"{s['optimistic by more than 2']}, better in "
                     f"{s['pessimistic by more than 2']}); median ratio "
                     f"{s['median test / promised']:.2f}, max {s['max test / promised']:.2f};"
                     f" worse than the highest fold in {s['worse than the highest fold']}, "
                     f"than twice it in {s['worse than twice the highest fold']}")
    return lines


def interval_detail(iv: dict, name: str = "default / best peer") -> str:
    lo, hi = iv[name]["interval"]
    if not math.isfinite(lo):
        return f"no interval ({iv['training sets']} training sets)"
    return (f"{100 * INTERVAL:.0f} % interval {lo:.3f}-{hi:.3f} over "
            f"{iv['training sets']} training sets")


def summary_rows(summary: dict, n_cases: int) -> list[dict]:
    """The bench runner's rows (its table and bench.json) from the summary."""
    rows = []
    for source, s in summary["per_source"].items():
        rows.append({"name": f"{source}: geomean default / best peer",
                     "value": s["geomean default / best peer"], "unit": "ratio",
                     "target": "<= 0.8" if source in TARGET_SOURCES else "",
                     "goal": goal("<=", 0.8) if source in TARGET_SOURCES else INFO,
                     "detail": f"{s['cases']} cases; " + interval_detail(s["intervals"])})
        loop = s["intervals"]["default / no effects"]
        rows.append({"name": f"{source}: geomean default / no effects (the loop)",
                     "value": loop["geomean"], "unit": "ratio", "goal": INFO,
                     "detail": interval_detail(s["intervals"], "default / no effects")})
        rows.append({"name": f"{source}: geomean default / strongest single peer",
                     "value": s["geomean default / strongest single peer"], "unit": "ratio",
                     "goal": INFO,
                     "detail": f"{s['strongest single peer']}, itself "
                     f"{s['geomean strongest single peer / best peer']:.2f}x the best per case"})
        rows.append({"name": f"{source}: geomean default / peer picked by validation",
                     "value": s["geomean default / peer picked by validation"],
                     "unit": "ratio", "goal": INFO,
                     "detail": "the peer with the lowest out-of-fold error "
                     "on the training file"})
        if "geomean default / oracle" in s:
            rows.append({"name": f"{source}: geomean default / its manifest's oracle",
                         "value": s["geomean default / oracle"], "unit": "ratio", "goal": INFO,
                         "detail": f"best peer {s['geomean best peer / oracle']:.2f}x; "
                         f"{s['cases with an oracle']} cases"})
        for target, v in s.get("against the oracle without hidden parts", {}).items():
            rows.append({"name": f"{source}: geomean default / oracle without hidden, {target}",
                         "value": v["geomean default / it"], "unit": "ratio", "goal": INFO,
                         "detail": f"best peer {v['geomean best peer / it']:.2f}x; perfect "
                         f"sensors on every measurable node; {v['cases']} cases"})
        cal = summary["calibration"][source]
        rows.append({"name": f"{source}: promised error within 2x of test", "value":
                     cal["within factor 2"], "unit": f"of {cal['cases']}", "goal": INFO,
                     "detail": f"test worse by > 2x in {cal['optimistic by more than 2']}, "
                     f"better in {cal['pessimistic by more than 2']}; median test / promised "
                     f"{cal['median test / promised']:.2f}; worse than twice the highest "
                     f"fold in {cal['worse than twice the highest fold']}"})
        rows.append({"name": f"{source}: test at or below the promise", "value":
                     cal.get("fraction at or below the promise", math.nan), "unit": "fraction",
                     "target": ">= 0.8", "goal": goal(">=", 0.8),
                     "detail": "above twice it: "
                     f"{cal.get('fraction above twice the promise', math.nan):.2f} "
                     "(target <= 0.05)"})
    rows.append({"name": "loop worse than its baseline by > 5 %",
                 "value": len(summary["loop_worse"]), "unit": f"of {n_cases}",
                 "target": "0", "goal": goal("==", 0)})
    return rows

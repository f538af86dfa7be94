"""Which extrapolation bound hurts unseen days less: on the inputs or on the output? (issue 41)

The box holds an axis when what it computes is beyond what training supports (docs/firmware.md,
BEYOND). Two families of rule, each with three margins, are compared on runs the model never
saw, against the model without any bound:

- ``none``: the model as it is (float, ``host.fitting.design_matrix`` terms);
- ``in25`` / ``in50`` / ``in100``: the box's input rule (BOX_BEYOND_SPAN_PERCENT): a channel
  reading beyond its training window (training range +- 5 %, codegen's EXTRAP window) by more
  than max(P % of the window's span, BOX_BEYOND_MIN_CODES = 5 degC) is a fault; the axes that
  read it hold and the channel's lag filters freeze (codegen.fixed.FixedModel.evaluate_run);
- ``inref25`` / ``inref50`` / ``inref100``: the same rule on each reading's change since the
  start reference (the range of that change over the training runs): what a start-referenced
  model reads; with ``reference none`` (FL) it is the input rule itself;
- ``out25`` / ``out50`` / ``out100``: an output-envelope rule: an axis holds while the model's
  value leaves [min, max] of its predictions over the training runs +- P % of that span. The
  value is the box's computed value (before the ZERO reference): ``outref*`` judges the
  referenced output instead (the change since the run's start, what the controller applies);
  with ``reference none`` (FL) the two are the same.

Hold = the output keeps its last computed value (no correction before the first); when the
hold ends the output walks back to the model at min(the axis's step limit ``max_step_um``,
BOX_SLEW_NM_PER_S x period) per sample, as codegen.fixed.AxisOutput does. Every rule, ``none``
too, goes through the same output stage, so a rule that never triggers scores exactly as
``none``. Not modelled: the plausibility guard, the clamp, the fixed-point rounding (identical
for every rule on these clean runs).

Models: ``host.train.train_model`` defaults (as ``host train``; ``nested=False``, which changes
the promise, not the model), trained and tested as bench/bench_accuracy.py's jobs do:

- ``sim``: the project's simulator, machines 0-2 (lag, ambient, speed effects); trained on a
  ``constant`` and a ``step`` day in a 20 degC shop; tested on the bench's ``random`` (21.5 degC)
  and ``sine`` (22 degC) days, and on the same two programs in a shop 8 degC warmer than
  training (28 degC): the honest hotter days;
- ``sim_dev``: ../shared/data/sim_dev, 3 machines x scenarios S0-S5 and S0_64 (train on
  ``*_train_*``, test on ``*_test_*``) plus S0 leave-one-run-out; dy/dz; ``start``;
- ``fl``: FL_THERMAL, each 8 h cycle held out in turn (all five probes on one box); and
  ``fl_next``: trained on the recording so far (cycles 1-2, 1-3), tested on the next, hotter
  and faster cycle (cycle 4 is the 5000 rpm cycle outside every training range).

Per held-out run and axis: tool error RMS and peak (um) of each rule (with ``start`` the error
of the referenced output against the referenced measurement, with ``none`` the plain error:
bench_accuracy.score), the share of samples held and walking back, and the run's largest
reading beyond a channel's EXTRAP window (degC: how near the input rule came). Summary per
source:
geometric mean over (run, axis) of each rule's RMS and peak over ``none``'s, the worst RMS
ratio, the mean share held, and how many cases / runs the rule triggers on at all; the same
for the hotter days alone (``sim`` +8 degC, ``fl`` cycle 4 out, ``fl_next``).

    .venv/bin/python scripts/extrapolation_bound.py            # every source, ~3-6 min, 1 core
    .venv/bin/python scripts/extrapolation_bound.py --quick    # one machine / job each, < 1 min

Writes build/extrapolation_bound.json (``-o``) and prints the table.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench import bench_accuracy as acc  # noqa: E402
from thermal_comp.contract.fixed_point import EXTRAPOLATION_MARGIN  # noqa: E402
from thermal_comp.contract.terms import TEMPERATURE_KINDS, Term  # noqa: E402
from thermal_comp.host.fitting import Reference, first_order_lag  # noqa: E402
from thermal_comp.host.fitting.features import term_values  # noqa: E402

DEFAULT_OUT = ROOT / "build" / "extrapolation_bound.json"
MARGINS_PCT = (25, 50, 100)
BEYOND_MIN_C = 5.0  # BOX_BEYOND_MIN_CODES 640 / 128
SLEW_UM_PER_S = 1.0  # BOX_SLEW_NM_PER_S 1000
HOT_AMBIENT_C = 28.0  # the sim's training shop is 20 degC: +8 degC
RULES = ("none", *(f"in{p}" for p in MARGINS_PCT), *(f"inref{p}" for p in MARGINS_PCT),
         *(f"out{p}" for p in MARGINS_PCT), *(f"outref{p}" for p in MARGINS_PCT))
TABLE_RULES = ("in25", "in50", "in100", "inref50", "out25", "out50", "out100", "outref50")


# --------------------------------------------------------------------------- cases

def sim_jobs(tmp: Path, seeds: Sequence[int]) -> list[acc.Job]:
    """bench_accuracy's sim jobs plus the same test programs in a shop +8 degC warmer."""
    from thermal_comp.host.sim import SimConfig, build_program, simulate, write_simulation

    jobs = []
    days = (("constant", 0, 8.0, 20.0, ""), ("step", 1, 8.0, 20.0, ""),
            ("random", 100, 13.0, 21.5, ""), ("sine", 101, 6.0, 22.0, ""),
            ("random", 100, 13.0, HOT_AMBIENT_C, " +8C"),
            ("sine", 101, 6.0, HOT_AMBIENT_C, " +8C"))
    for m in seeds:
        specs = []
        for protocol, offset, start_hour, ambient, tag in days:
            seed = 1000 * m + offset
            program = build_program(protocol, hours=8.0, cool_hours=8.0, seed=seed)
            sim = simulate(program, SimConfig(seed=seed, machine_seed=m,
                                              effects=acc.SIM_EFFECTS,
                                              start_hour=start_hour, ambient_c=ambient))
            label = f"{protocol}{tag}"
            path = tmp / f"sim_m{m}_{label.replace(' ', '_')}.csv"
            write_simulation(sim, path)
            specs.append(acc.RunSpec(str(path), label=label))
        jobs.append(acc.Job("sim", f"machine {m}", tuple(specs[:2]), tuple(specs[2:]),
                            tuple(acc.SIM_TARGETS), "start",
                            bending=acc.declared_bending("sim")))
    return jobs


def all_jobs(tmp: Path, quick: bool, sources: Sequence[str]) -> list[acc.Job]:
    jobs: list[acc.Job] = []
    if "sim" in sources:
        jobs += sim_jobs(tmp, (0,) if quick else acc.SIM_SEEDS)
    if "sim_dev" in sources:
        dev = acc.dev_jobs(big=not quick)
        if quick:
            dev = [j for j in dev if j.group in ("machine11 S0", "machine11 S2")]
        jobs += dev
    if "fl" in sources:
        fl = acc.fl_jobs()
        jobs += [fl[-1]] if quick else fl
        nxt = acc.fl_next_jobs()
        jobs += [nxt[-1]] if quick else nxt
    return jobs


def is_hot(source: str, group: str, test: str) -> bool:
    """The constructed or recorded days outside training: the sim +8 degC days, FL cycle 4
    (5000 rpm, hotter than every other cycle) held out, and FL forward in time."""
    return (source == "sim" and test.endswith("+8C")) or source == "fl_next" or (
        source == "fl" and test == "cycle 4")


# --------------------------------------------------------------------------- the model

@dataclass
class AxisModel:
    terms: list[Term]
    coefs: np.ndarray
    intercept: float
    channels: set[str]  # temperature sources its terms read
    step_um: float  # the box's tracking step limit (max_step_um)


def axis_models(model: dict) -> dict[str, AxisModel]:
    out = {}
    period = float(model["sample_period_s"])
    for name, spec in model["axes"].items():
        terms = [Term.from_json(t) for t in spec["terms"]]
        coefs = np.array([float(t["coef"]) for t in spec["terms"]])
        chans = {t.source for t in terms if t.kind in TEMPERATURE_KINDS and t.source}
        step = float(spec.get("max_step_um", SLEW_UM_PER_S * period))
        out[name] = AxisModel(terms, coefs, float(spec["intercept"]), chans, step)
    return out


def frozen_lag(x: np.ndarray, alpha: float, ok: np.ndarray) -> np.ndarray:
    """first_order_lag whose state updates only where ``ok`` (frozen while faulted, cold start
    at the first valid sample); before it the value is the first valid reading."""
    idx = np.flatnonzero(ok)
    if idx.size == 0:
        return np.zeros_like(x, dtype=float)
    y = first_order_lag(x[idx], alpha)
    pos = np.searchsorted(idx, np.arange(x.size), side="right") - 1
    return y[np.maximum(pos, 0)]


def evaluate(ax: AxisModel, columns: dict, period_s: float,
             valid: dict[str, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(the axis's float value, computed mask): with ``valid`` (channel -> bool per sample)
    the filters of a faulted channel freeze and the axis is computed only where every
    temperature input is valid."""
    n = len(next(iter(columns.values())))
    ok = np.ones(n, dtype=bool)
    value = np.full(n, ax.intercept)
    for term, coef in zip(ax.terms, ax.coefs, strict=True):
        mask = None if valid is None or term.source not in valid else valid[term.source]
        if mask is not None and not mask.all() and term.kind in ("lag", "rate"):
            x = np.asarray(columns[term.source], dtype=float)
            lag = frozen_lag(x, term.params["alpha"], mask)
            f = lag if term.kind == "lag" else x - lag
        else:
            f = term_values(term, columns, period_s)
        value += coef * f
        if mask is not None:
            ok &= mask
    return value, ok


def windows(model: dict) -> dict[str, tuple[float, float]]:
    """Per channel: codegen's EXTRAP window (training range +- 5 %), degC."""
    out = {}
    for c in model["channels"]:
        if "trained_min_c" in c:
            lo, hi = float(c["trained_min_c"]), float(c["trained_max_c"])
            m = (hi - lo) * float(EXTRAPOLATION_MARGIN)
            out[c["sensor"]] = (lo - m, hi + m)
    return out


def input_limits(model: dict, pct: float,
                 ranges: dict[str, tuple[float, float]] | None = None
                 ) -> dict[str, tuple[float, float]]:
    """Per channel: the readings (degC) beyond which the box says BEYOND (hil/expect.py
    OutputConfig.beyond_limits, in degC instead of codes). ``ranges``: other training ranges
    than the model's (the referenced readings' for ``inref``)."""
    out = {}
    for c in model["channels"]:
        if "trained_min_c" not in c:
            continue
        lo, hi = (float(c["trained_min_c"]), float(c["trained_max_c"])) if ranges is None \
            else ranges[c["sensor"]]
        m = (hi - lo) * float(EXTRAPOLATION_MARGIN)
        wlo, whi = lo - m, hi + m
        margin = max((whi - wlo) * pct / 100.0, BEYOND_MIN_C)
        out[c["sensor"]] = (wlo - margin, whi + margin)
    return out


def output_stage(value: np.ndarray, computed: np.ndarray, track_um: float, walk_um: float
                 ) -> tuple[np.ndarray, int, int]:
    """The box's output for a referenced model value: hold at the last computed value (0
    before the first), walk back after a hold at min(track, walk) per sample, track at
    ``track_um`` per sample. Returns (output, samples held, samples walking back)."""
    out = np.empty_like(value)
    cur, has, walking = 0.0, False, False
    held = walked = 0
    v, ok = value.tolist(), computed.tolist()
    back = min(track_um, walk_um)
    for i in range(len(v)):
        if not ok[i]:
            held += 1
            walking = walking or has
            out[i] = cur
            continue
        if not has:
            cur, has = v[i], True
            out[i] = cur
            continue
        step = back if walking else track_um
        diff = v[i] - cur
        if -step <= diff <= step:
            cur, walking = v[i], False
        else:
            cur += step if diff > 0 else -step
            walked += walking
        out[i] = cur
    return out, held, walked


# --------------------------------------------------------------------------- one job

@dataclass
class Case:
    source: str
    group: str
    test: str
    axis: str
    hot: bool
    n: int
    excursion_c: float = 0.0  # the run's largest reading beyond a channel's EXTRAP window
    rms_um: dict[str, float] = field(default_factory=dict)
    peak_um: dict[str, float] = field(default_factory=dict)
    held: dict[str, float] = field(default_factory=dict)  # share of samples held
    walked: dict[str, float] = field(default_factory=dict)  # share walking back after a hold
    notes: dict[str, str] = field(default_factory=dict)


def run_job(job: acc.Job) -> list[Case]:
    from thermal_comp.host.train import train_model

    targets = list(job.targets)
    train = [acc._load(s, targets) for s in job.train]
    test = [(s, acc._load(s, targets)) for s in job.test]
    kwargs = acc.train_kwargs(job.reference, job.bending, targets)
    model = train_model(train, targets, aux=acc.AUX, nested=False, **kwargs)
    period = float(model["sample_period_s"])
    ref = Reference.of_model(model)
    axes = axis_models(model)
    walk_um = SLEW_UM_PER_S * period
    # the training envelope of each axis: raw (the box's computed value) and referenced
    env: dict[str, dict[str, tuple[float, float]]] = {}
    for name, ax in axes.items():
        raw = [evaluate(ax, r.columns(), period)[0] for r in train]
        referenced = [ref.apply(p) for p in raw]
        env[name] = {"out": (min(float(p.min()) for p in raw), max(float(p.max()) for p in raw)),
                     "outref": (min(float(p.min()) for p in referenced),
                                max(float(p.max()) for p in referenced))}
    limits = {f"in{p}": input_limits(model, p) for p in MARGINS_PCT}
    # inref: the same rule on each reading's change since the start reference (what a
    # start-referenced model reads); with reference none it is the input rule itself
    wins = windows(model)
    ref_ranges = {ch: (min(float(ref.apply(r.column(ch)).min()) for r in train),
                       max(float(ref.apply(r.column(ch)).max()) for r in train)) for ch in wins}
    limits |= {f"inref{p}": input_limits(model, p, ref_ranges) for p in MARGINS_PCT}
    cases = []
    for spec, run in test:
        cols = run.columns()
        readings = {"in": {ch: np.asarray(cols[ch], dtype=float) for ch in wins}}
        readings["inref"] = {ch: ref.apply(x) for ch, x in readings["in"].items()}
        inside = {rule: {ch: (readings[rule.rstrip("0123456789")][ch] >= lo)
                         & (readings[rule.rstrip("0123456789")][ch] <= hi)
                         for ch, (lo, hi) in lim.items()} for rule, lim in limits.items()}
        excursion = max((max(float(x.max()) - wins[ch][1], wins[ch][0] - float(x.min()), 0.0)
                         for ch, x in readings["in"].items()), default=0.0)
        for name, ax in axes.items():
            measured = ref.apply(run.target(name))
            raw, _ = evaluate(ax, cols, period)
            value = {"none": (ref.apply(raw), np.ones(raw.size, dtype=bool))}
            for p in MARGINS_PCT:
                for kind in ("in", "inref"):
                    v, ok = evaluate(ax, cols, period, inside[f"{kind}{p}"])
                    # the box's ZERO is taken of the computed values: here the unbounded
                    # model's reference (no correction at all while held from power-up)
                    value[f"{kind}{p}"] = (ref.apply(np.where(ok, v, raw)), ok)
                for kind, series in (("out", raw), ("outref", value["none"][0])):
                    lo, hi = env[name][kind]
                    m = (hi - lo) * p / 100.0
                    value[f"{kind}{p}"] = (value["none"][0],
                                           (series >= lo - m) & (series <= hi + m))
            case = Case(job.source, job.group, spec.name, name,
                        is_hot(job.source, job.group, spec.name), int(raw.size),
                        excursion_c=excursion)
            for rule in RULES:
                v, ok = value[rule]
                out, held, walked = output_stage(v, ok, ax.step_um, walk_um)
                err = out - measured
                case.rms_um[rule] = float(np.sqrt(np.mean(err * err)))
                case.peak_um[rule] = float(np.max(np.abs(err)))
                case.held[rule] = held / raw.size
                case.walked[rule] = walked / raw.size
            cases.append(case)
    return cases


# --------------------------------------------------------------------------- summary

def gmean(x: Sequence[float]) -> float:
    x = [v for v in x if v > 0 and math.isfinite(v)]
    return math.exp(sum(math.log(v) for v in x) / len(x)) if x else math.nan


def summarise(cases: Sequence[Case]) -> dict[str, dict]:
    out: dict[str, dict] = {}
    for rule in RULES:
        runs = {(c.source, c.group, c.test) for c in cases}
        trig_runs = {(c.source, c.group, c.test) for c in cases if c.held[rule] > 0}
        rms = [c.rms_um[rule] / c.rms_um["none"] for c in cases]
        peak = [c.peak_um[rule] / c.peak_um["none"] for c in cases]
        out[rule] = {"gm_rms_ratio": gmean(rms), "gm_peak_ratio": gmean(peak),
                     "worst_rms_ratio": max(rms), "best_rms_ratio": min(rms),
                     "held_pct": 100 * float(np.mean([c.held[rule] for c in cases])),
                     "walked_pct": 100 * float(np.mean([c.walked[rule] for c in cases])),
                     "cases": len(cases),
                     "max_excursion_c": max(c.excursion_c for c in cases),
                     "cases_triggered": sum(c.held[rule] > 0 for c in cases),
                     "runs": len(runs), "runs_triggered": len(trig_runs),
                     "cases_better": sum(c.rms_um[rule] < c.rms_um["none"] * 0.999
                                         for c in cases),
                     "cases_worse": sum(c.rms_um[rule] > c.rms_um["none"] * 1.001
                                        for c in cases)}
    return out


def groups_of(cases: Sequence[Case]) -> dict[str, list[Case]]:
    sources = sorted({c.source for c in cases}, key=lambda s: acc.SOURCES.index(s))
    out: dict[str, list[Case]] = {}
    for s in sources:
        mine = [c for c in cases if c.source == s]
        out[s] = mine
        hot = [c for c in mine if c.hot]
        if hot and len(hot) < len(mine):
            out[f"{s} hot"] = hot
            out[f"{s} ordinary"] = [c for c in mine if not c.hot]
    return out


def table(summary: dict[str, dict]) -> str:
    lines = []
    head = f"{'group':<16} {'rule':<9} {'RMS/none':>8} {'peak/none':>9} {'worst':>6} " \
           f"{'held %':>7} {'cases trig':>10} {'runs trig':>9} {'better/worse':>12}"
    lines.append(head)
    lines.append("-" * len(head))
    for group, per_rule in summary.items():
        none = per_rule["none"]
        lines.append(f"{group:<16} {'none':<9} {'1':>8} {'1':>9} {'':>6} {0:>7.2f} "
                     f"{'':>10} {'':>9} {'':>12}   ({none['cases']} cases, {none['runs']} runs; "
                     f"up to {none['max_excursion_c']:.1f} degC beyond a window)")
        for rule in TABLE_RULES:
            r = per_rule[rule]
            lines.append(f"{'':<16} {rule:<9} {r['gm_rms_ratio']:>8.3f} "
                         f"{r['gm_peak_ratio']:>9.3f} {r['worst_rms_ratio']:>6.2f} "
                         f"{r['held_pct']:>7.2f} "
                         f"{r['cases_triggered']:>4}/{r['cases']:<5} "
                         f"{r['runs_triggered']:>3}/{r['runs']:<5} "
                         f"{r['cases_better']:>5}/{r['cases_worse']:<6}")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true",
                    help="one sim machine, two sim_dev jobs, FL cycle 4 out and cycles 1-3 "
                         "-> 4 (< 1 min)")
    ap.add_argument("--source", action="append", choices=("sim", "sim_dev", "fl"),
                    help="only these sources (repeatable; fl includes fl_next; default all)")
    ap.add_argument("-o", "--out", type=Path, default=DEFAULT_OUT,
                    help=f"JSON written (default {DEFAULT_OUT.relative_to(ROOT)})")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    cases: list[Case] = []
    with tempfile.TemporaryDirectory() as tmp:
        jobs = all_jobs(Path(tmp), args.quick, args.source or ("sim", "sim_dev", "fl"))
        for k, job in enumerate(jobs, 1):
            cases += run_job(job)
            print(f"[{k}/{len(jobs)}] {job.source} {job.group} "
                  f"({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    summary = {g: summarise(cs) for g, cs in groups_of(cases).items()}
    print(table(summary))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({
        "quick": args.quick, "margins_pct": list(MARGINS_PCT), "beyond_min_c": BEYOND_MIN_C,
        "rules": list(RULES), "summary": summary,
        "cases": [c.__dict__ for c in cases]}, indent=1))
    print(f"wrote {args.out} ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

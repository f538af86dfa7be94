"""`host compare TRAIN.csv... --test TEST.csv... --target dz_um`: ours vs its peers."""

from __future__ import annotations

import argparse
import json

from thermal_comp.contract.box import BOX_CHANNELS
from thermal_comp.contract.errors import InputError
from thermal_comp.contract.model_file import jsonable
from thermal_comp.host.analysis import DEFAULT_K_CORRELATED, EXHAUSTIVE_LIMIT, compare_methods
from thermal_comp.host.commands._options import csv_format
from thermal_comp.host.commands.train import add_data_arguments, add_selection_arguments
from thermal_comp.host.io import check_variation, load_runs, window

NAME = "compare"
HELP = ("train the box's model, our selections (validated, refined, paper-exact) and peer "
        "methods; compare test RMSE")


def register(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("runs", nargs="+", metavar="TRAIN.csv", help="training runs")
    parser.add_argument("--test", nargs="+", metavar="TEST.csv", default=[],
                        help="test runs (never seen in training)")
    parser.add_argument("--split-at-h", type=float, default=None, metavar="H",
                        help="instead of --test: train on each run before H hours, test on "
                        "the rest (e.g. 24 for examples/fl_thermal_steps.csv)")
    add_data_arguments(parser)
    add_selection_arguments(parser)
    parser.add_argument("--engineering", default=None, metavar="T01,T05,...",
                        help="a hand-picked sensor set to compare against")
    parser.add_argument("--k-correlated", type=int, default=DEFAULT_K_CORRELATED, metavar="K",
                        help="sensors of the most-correlated peer (paper 002: %(default)s)")
    parser.add_argument("--exhaustive-limit", type=int, default=EXHAUSTIVE_LIMIT, metavar="N",
                        help="skip the exhaustive search above N subsets (default %(default)s)")
    parser.add_argument("--json", action="store_true", help="print JSON on stdout")


def _fmt(x) -> str:
    return "-" if x is None or x != x else f"{x:.3f}"


def print_table(doc: dict) -> None:
    print(f"train: {', '.join(doc['train'])}\ntest:  {', '.join(doc['test'])}\n"
          f"validation inside training: {doc['validation']}")
    for axis, a in doc["axes"].items():
        print(f"\n{axis} (test raw RMS {_fmt(a['raw_rms_um'])} um)")
        print(f"  {'method':<48} {'n':>3} {'test rmse um':>12} {'max|e| um':>10} "
              f"{'fit s':>7}  sensors / note")
        for m in a["methods"]:
            extra = ",".join(m["sensors"]) if len(m["sensors"]) <= 8 else \
                f"{','.join(m['sensors'][:8])},..."
            if m["note"]:
                extra = f"{extra} ({m['note']})" if extra else m["note"]
            print(f"  {m['method']:<48} {m['n_sensors']:>3} {_fmt(m['test_rmse_um']):>12} "
                  f"{_fmt(m['test_max_abs_um']):>10} {m['fit_time_s']:>7.2f}  {extra}")
        best, in_box = a.get("best"), a.get("best_within_box")
        if best:
            print(f"  best on this test: {best['method']} ({_fmt(best['test_rmse_um'])} um)")
        if in_box and in_box != best:
            print(f"  best the box can read (<= {BOX_CHANNELS} sensors): {in_box['method']} "
                  f"({_fmt(in_box['test_rmse_um'])} um)")


def run(args: argparse.Namespace) -> int:
    fmt = csv_format(args)
    runs = load_runs(args.runs, args.target, args.sensors, args.aux, args.fill_gaps,
                     min_samples=4, fmt=fmt)
    check_variation(runs, args.target)
    if args.split_at_h is not None:
        if args.test:
            raise InputError("give either --test or --split-at-h, not both")
        at = args.split_at_h * 3600.0
        train = [window(r, None, at) for r in runs]
        test = [window(r, at, None) for r in runs]
    else:
        if not args.test:
            raise InputError("give test runs with --test (or --split-at-h H)")
        train = runs
        test = load_runs(args.test, args.target, args.sensors, args.aux, args.fill_gaps,
                         fmt=fmt)
    engineering = [s.strip() for s in args.engineering.split(",") if s.strip()] \
        if args.engineering else None
    doc = compare_methods(train, test, args.target, engineering=engineering,
                          k_correlated=args.k_correlated, max_sensors=args.max_sensors,
                          groups=args.groups, n_blocks=args.blocks,
                          max_delay_s=None if args.max_delay_h is None else args.max_delay_h * 3600,
                          exhaustive_limit=args.exhaustive_limit, seed=args.seed,
                          reference=args.reference, aux=args.aux,
                          bending=args.bending, quiet=args.json)
    if args.json:
        print(json.dumps(jsonable(doc), indent=2, allow_nan=False))
    else:
        print_table(doc)
    return 0

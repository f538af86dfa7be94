"""`host compare-protocols`: train on each thermal-test protocol, test on all (paper 002)."""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from thermal_comp.contract.errors import InputError
from thermal_comp.host.analysis import (
    AXES,
    combine,
    compare_protocols,
    format_matrix,
    parse_runs,
    simulate_runs,
    write_outputs,
)
from thermal_comp.host.commands._arguments import hours_arg, seed_arg
from thermal_comp.host.sim import PROTOCOLS, parse_effects

NAME = "compare-protocols"
DEFAULT_REPEATS = 3
HELP = ("train a model on each test protocol and test it on runs of every other protocol "
        "(simulated, or your --runs)")


def register(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--runs", nargs="+", metavar="NAME=RUN.csv",
                        help="measured runs instead of simulation; the first run of a name "
                        "trains, a second one (another day) is its test run")
    parser.add_argument("--protocols", default=",".join(PROTOCOLS), metavar="LIST",
                        help="simulated protocols (default constant,step,random,sine)")
    parser.add_argument("--no-production", action="store_true",
                        help="skip the simulated random 'production day' test run")
    parser.add_argument("--sim-effects", default="", metavar="LIST",
                        help="effects in the simulated runs (see host simulate --effects)")
    parser.add_argument("--max-rpm", type=float, default=8000.0,
                        help="simulated spindle's top speed (rpm, default %(default)g)")
    parser.add_argument("--hours", type=hours_arg, default=8.0,
                        help="simulated running time of each test (h, default %(default)g)")
    parser.add_argument("--cool-hours", type=hours_arg, default=8.0,
                        help="simulated cooling time after it (h, default %(default)g)")
    parser.add_argument("--dt", type=float, default=60.0, help="simulated sample period (s)")
    parser.add_argument("--sim-sensors", type=int, default=16, metavar="N",
                        help="simulated thermocouples (default 16, plus T_amb)")
    parser.add_argument("--seed", type=seed_arg, default=0, help="first seed of the simulated days")
    parser.add_argument("--repeats", type=int, default=None, metavar="N",
                        help="simulate the whole comparison on N sets of days, average them "
                        f"and show the spread; a winner is declared only when it beats the "
                        f"runner-up by more than the spread (default {DEFAULT_REPEATS})")
    parser.add_argument("--target", action="append", metavar="COLUMN",
                        help="displacement column (repeatable; default dx_um, dy_um, dz_um)")
    parser.add_argument("--sensors", default="T*", metavar="GLOB",
                        help="temperature columns offered to training (default 'T*')")
    parser.add_argument("--aux", action="append", default=[], metavar="COLUMN",
                        help="auxiliary input offered to training (e.g. spindle_rpm)")
    parser.add_argument("--max-sensors", type=int, default=5,
                        help="most sensors per axis in each trained model (default %(default)s)")
    parser.add_argument("--groups", type=int, default=10,
                        help="c-means groups of the selection (default %(default)s)")
    parser.add_argument("--fit-effects", action="store_true",
                        help="let training add effect terms (lag, rate, ambient, ...: "
                        "docs/effects.md); default static models as in paper 002")
    parser.add_argument("--out", metavar="DIR",
                        help="write protocols.csv and protocols.json (and the simulated runs "
                        "under DIR/runs) here")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")


def run(args: argparse.Namespace) -> int:
    targets = args.target or list(AXES)
    quiet = args.json
    if args.repeats is not None and args.repeats < 1:
        raise InputError(f"--repeats must be at least 1 (got {args.repeats})")
    if args.runs and args.repeats is not None and args.repeats > 1:
        raise InputError("--repeats applies to simulated runs; with --runs give more runs")
    repeats = DEFAULT_REPEATS if args.repeats is None else args.repeats
    train = dict(sensors=args.sensors, aux=args.aux, max_sensors=args.max_sensors,
                 groups=args.groups, fit_effects=args.fit_effects, quiet=quiet)
    with tempfile.TemporaryDirectory(prefix="compare-protocols-") as tmp:
        if args.runs:
            comp = compare_protocols(parse_runs(args.runs), targets, **train)
        else:
            protocols = [p.strip() for p in args.protocols.split(",") if p.strip()]
            comps = []
            for r in range(repeats):
                run_dir = (Path(args.out) / "runs" if args.out else Path(tmp)) / f"repeat{r + 1}"
                runs = simulate_runs(run_dir, protocols, max_rpm=args.max_rpm,
                                     hours=args.hours, cool_hours=args.cool_hours,
                                     dt_s=args.dt, n_sensors=args.sim_sensors,
                                     effects=parse_effects(args.sim_effects),
                                     seed=args.seed + 1000 * r,
                                     production=not args.no_production, quiet=quiet)
                comps.append(compare_protocols(runs, targets, **train))
            comp = combine(comps)
            comp.settings["simulation"] = {
                "protocols": protocols, "effects": list(parse_effects(args.sim_effects)),
                "hours": args.hours, "cool_hours": args.cool_hours, "dt_s": args.dt,
                "sensors": args.sim_sensors, "max_rpm": args.max_rpm, "seed": args.seed,
                "repeats": repeats}
            if not args.out:
                comp.runs = {k: [Path(p).name for p in v] for k, v in comp.runs.items()}
        written = write_outputs(comp, args.out) if args.out else []
    if args.json:
        print(json.dumps(comp.to_json(), indent=2))
        return 0
    print(format_matrix(comp))
    for path in written:
        print(f"wrote {path}")
    return 0

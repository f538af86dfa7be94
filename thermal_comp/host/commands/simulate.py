"""`host simulate`: write a simulated thermal test run (CSV + .truth.json); docs/simulator.md."""

from __future__ import annotations

import argparse
import json

import numpy as np

from thermal_comp.contract.errors import InputError
from thermal_comp.host.commands._arguments import hours_arg, seed_arg
from thermal_comp.host.sim import (
    AXES,
    EFFECTS,
    PROTOCOLS,
    SimConfig,
    build_program,
    parse_effects,
    simulate,
    write_simulation,
)

NAME = "simulate"
HELP = "simulate a thermal test run of a vertical machining center (CSV + truth sidecar)"


def add_program_arguments(parser: argparse.ArgumentParser) -> None:
    """Spindle program options shared with `host testplan`."""
    parser.add_argument("--protocol", choices=PROTOCOLS, default="constant",
                        help="spindle program (default: constant at 75%% of --max-rpm)")
    parser.add_argument("--max-rpm", type=float, default=8000.0,
                        help="maximum spindle speed (default 8000)")
    parser.add_argument("--hours", type=hours_arg, default=8.0,
                        help="running phase in hours (default 8)")
    parser.add_argument("--cool-hours", type=hours_arg, default=8.0,
                        help="cooling phase at standstill in hours (default 8)")
    parser.add_argument("--rpm", type=float, default=None,
                        help="speed of the constant protocol (default 75%% of --max-rpm)")
    parser.add_argument("--seed", type=seed_arg, default=0,
                        help="seed of the random program, the noise and the day (default 0)")


def register(parser: argparse.ArgumentParser) -> None:
    add_program_arguments(parser)
    parser.add_argument("-o", "--out", required=True, metavar="RUN.csv",
                        help="run CSV to write; the truth goes to RUN.truth.json beside it")
    parser.add_argument("--dt", type=float, default=60.0, help="sample period in s (default 60)")
    parser.add_argument("--sensors", type=int, default=16, metavar="N",
                        help="number of thermocouples T01..TN (plus T_amb; default 16)")
    parser.add_argument("--effects", default="", metavar="LIST",
                        help=f"comma-separated effects to switch on: {', '.join(EFFECTS)}, "
                        "or 'all' (default none)")
    parser.add_argument("--machine-seed", type=seed_arg, default=0,
                        help="seed of the machine's sensor placement (same machine: same seed)")
    parser.add_argument("--ambient-c", type=float, default=20.0,
                        help="shop air at the start in degC (default 20)")
    parser.add_argument("--start-hour", type=float, default=8.0,
                        help="time of day at the start, for the daily cycle (default 8)")
    parser.add_argument("--precision", type=int, default=6,
                        help="significant digits in the CSV (default 6)")
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")


MAX_SAMPLES = 10_000_000  # 116 days at 1 s: far beyond a thermal test, still fits memory


def run(args: argparse.Namespace) -> int:
    if not (np.isfinite(args.dt) and args.dt > 0):
        raise InputError(f"--dt {args.dt:g} s: the sample period must be a positive number")
    samples = (args.hours + args.cool_hours) * 3600.0 / args.dt
    if samples > MAX_SAMPLES:
        raise InputError(f"--hours {args.hours:g} + --cool-hours {args.cool_hours:g} at --dt "
                         f"{args.dt:g} s is {samples:.3g} samples, more than {MAX_SAMPLES:,}: "
                         "shorten the run or sample less often")
    program = build_program(args.protocol, args.max_rpm, args.hours, args.cool_hours,
                            seed=args.seed, rpm=args.rpm)
    if not 3 <= args.precision <= 17:
        raise InputError(f"--precision must be 3..17 significant digits (got {args.precision})")
    config = SimConfig(n_sensors=args.sensors, dt_s=args.dt, seed=args.seed,
                       machine_seed=args.machine_seed, effects=parse_effects(args.effects),
                       ambient_c=args.ambient_c, start_hour=args.start_hour)
    sim = simulate(program, config)
    truth_path = write_simulation(sim, args.out, precision=args.precision)
    summary = {
        "run": str(args.out), "truth": str(truth_path), "protocol": args.protocol,
        "samples": int(sim.time_s.size), "dt_s": args.dt, "sensors": sim.sensor_names,
        "effects": {e: {k: v for k, v in p.items() if k in ("sensor", "matching_terms")}
                    for e, p in sim.truth["effects"].items()},
        "max_abs_um": {a: round(float(np.max(np.abs(sim.displacement_true[a]))), 3)
                       for a in AXES},
        "max_rise_c": round(float(np.max(sim.nodes_c - sim.nodes_c[0])), 3),
    }
    if args.json:
        print(json.dumps(summary, indent=2))
        return 0
    print(f"wrote {summary['run']} ({summary['samples']} samples every {args.dt:g} s, "
          f"{len(sim.sensor_names)} temperatures, protocol {args.protocol})")
    print(f"truth in {summary['truth']}; effects: {', '.join(sim.truth['effects']) or 'none'}")
    print("max |displacement| (noise-free): " + ", ".join(
        f"{a} {v:.1f} um" for a, v in summary["max_abs_um"].items())
        + f"; hottest node rise {summary['max_rise_c']:.1f} K")
    return 0

"""`host testplan`: write the NC program of a thermal test (paper 002 procedure)."""

from __future__ import annotations

import argparse
import json
import sys

from thermal_comp.host.commands.simulate import add_program_arguments
from thermal_comp.host.sim import DIALECTS, ThermalTestPlan, build_program, parse_duration

NAME = "testplan"
HELP = "write the G-code program that runs a thermal test (speed schedule + measurement stops)"


def register(parser: argparse.ArgumentParser) -> None:
    add_program_arguments(parser)
    parser.add_argument("-o", "--out", required=True, metavar="PROGRAM.nc",
                        help="NC program to write ('-' for standard output)")
    parser.add_argument("--measure-every", default="5min", metavar="DURATION",
                        help="measurement cadence, e.g. 300s, 5min (default 5min)")
    parser.add_argument("--measure-time", default="10s", metavar="DURATION",
                        help="spindle stop for each measurement (default 10s)")
    parser.add_argument("--trigger", default="M100",
                        help="M-code wired to the logger's trigger input (default M100); "
                        "with --dialect linuxcnc a user M-code M100-M199 (called with P = "
                        "measurement number) or 'M64 P<n>' (digital output n on during each "
                        "measurement stop)")
    parser.add_argument("--dialect", choices=DIALECTS, default="rs274",
                        help="dwell word: rs274 'G4 P<s>.' (Haas, RS274/NGC), fanuc "
                        "'G4 X<s>.', linuxcnc 'G4 P<s>.' plus LinuxCNC's triggers "
                        "(default rs274)")
    parser.add_argument("--program-number", type=int, default=1000,
                        help="O-number of the program (default 1000)")
    parser.add_argument("--json", action="store_true", help="print a summary as JSON")


def run(args: argparse.Namespace) -> int:
    program = build_program(args.protocol, args.max_rpm, args.hours, args.cool_hours,
                            seed=args.seed, rpm=args.rpm)
    plan = ThermalTestPlan(program, parse_duration(args.measure_every, "--measure-every"),
                    parse_duration(args.measure_time, "--measure-time"), args.trigger,
                    args.dialect, args.program_number)
    text = plan.render()
    if args.out == "-":
        sys.stdout.write(text)
        return 0
    plan.write(args.out)
    summary = {"program": str(args.out), "protocol": args.protocol, "max_rpm": args.max_rpm,
               "measurements": plan.n_intervals + 1, "cycle_time_s": plan.duration_s,
               "lines": text.count("\n"), "mean_run_fraction": round(
                   program.mean_run_fraction(), 4)}
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(f"wrote {args.out}: {args.protocol} test, {summary['measurements']} measurements, "
              f"cycle time {plan.duration_s / 3600:.2f} h, {summary['lines']} lines")
    return 0

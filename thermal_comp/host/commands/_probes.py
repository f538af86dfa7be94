"""Probe options of the commands that replay a run in service (issue 42, docs/service.md).

Not a command (its name starts with _). ``--probe-every`` synthesises readings from the run's
measured displacement; without it a run's logged ``probe_<axis>`` columns are used as they
are; with neither there are no readings.
"""

from __future__ import annotations

import argparse

from thermal_comp.host.analysis.service import readings_for
from thermal_comp.host.commands._arguments import seed_arg
from thermal_comp.host.io import CsvFormat, Run
from thermal_comp.host.service import PROBE_WHEN, ProbePlan, ProbeReadings
from thermal_comp.host.service.probes import ProbeError, duration_s


def _duration(text: str) -> float:
    try:
        return duration_s(text)
    except ProbeError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("--probe-every: ")) from None


def _noise(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of um") from None
    if not 0 <= v <= 100:  # also refuses nan and inf
        raise argparse.ArgumentTypeError(f"{text} um must be between 0 and 100")
    return v


def add_probe_arguments(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group(
        "in service (docs/service.md)", "a touch probe's readings update the model between "
        "thermal tests; without --probe-every a run's logged probe_<axis> columns are used")
    g.add_argument("--probe-every", type=_duration, default=None, metavar="DURATION",
                   help="synthesise a probe reading every DURATION (60min, 2h, 900s)")
    g.add_argument("--probe-noise-um", type=_noise, default=0.5, metavar="X",
                   help="the synthesised readings' noise, standard deviation (default 0.5)")
    g.add_argument("--probe-seed", type=seed_arg, default=0, metavar="N",
                   help="seed of the synthesised noise (default 0)")
    g.add_argument("--probe-when", choices=PROBE_WHEN, default="interval",
                   help="interval: on the clock; stopped: only while the spindle stands "
                   "(spindle_rpm at or below 1), as at a tool change (default interval)")


def probe_plan(args: argparse.Namespace) -> ProbePlan | None:
    """The synthesised readings the options ask for (--probe-every), or None."""
    if args.probe_every is None:
        return None
    return ProbePlan(args.probe_every, args.probe_noise_um, args.probe_seed, args.probe_when)


def probe_readings(args: argparse.Namespace, model: dict, run: Run,
                   fmt: CsvFormat | None = None) -> ProbeReadings | None:
    """The readings the options ask for, or None (no --probe-every, nothing logged)."""
    return readings_for(model, run, probe_plan(args), args.reference, fmt)

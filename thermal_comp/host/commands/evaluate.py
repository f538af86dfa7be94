"""`host evaluate MODEL.json RUN.csv [--json]`: residual of a model on a run it never saw."""

from __future__ import annotations

import argparse
import json

from thermal_comp.contract.model_file import jsonable, read_model
from thermal_comp.contract.tilt import unit_of
from thermal_comp.host.analysis import evaluate_model, load_for_model
from thermal_comp.host.analysis.service import service_of
from thermal_comp.host.commands._arguments import add_reference_argument
from thermal_comp.host.commands._options import add_fill_gaps, csv_format
from thermal_comp.host.commands._probes import add_probe_arguments, probe_readings
from thermal_comp.host.train import describe, input_units

NAME = "evaluate"
HELP = "evaluate a model.json on a run: residual RMSE, peak, raw drift and reduction per axis"


def register(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", metavar="MODEL.json")
    parser.add_argument("run", metavar="RUN.csv")
    add_reference_argument(parser, training=False)
    add_fill_gaps(parser)
    parser.add_argument("--json", action="store_true", help="print JSON on stdout")
    add_probe_arguments(parser)


def run(args: argparse.Namespace) -> int:
    model = read_model(args.model)
    data = load_for_model(args.run, model, args.fill_gaps, fmt=csv_format(args))
    doc = {"model": args.model, **evaluate_model(model, data, args.reference)}
    readings = probe_readings(args, model, data, csv_format(args))
    if readings is not None:  # issue 42: the model updated by the probe (docs/service.md)
        doc["probes"] = readings.source
        for axis, m in service_of(model, data, readings, args.reference).items():
            a = doc["axes"][axis]
            a.update(m)
            if a["raw_rms_um"] > 0:
                a["reduction_pct"] = 100.0 * (1.0 - a["rmse_um"] / a["raw_rms_um"])
    if args.json:
        print(json.dumps(jsonable(doc), indent=2, allow_nan=False))
        return 0
    print(f"model {args.model} on {args.run} ({data.n_samples} samples)")
    print(f"{'axis':<10} {'rmse um':>9} {'max|e| um':>10} {'raw rms um':>11} {'raw peak um':>12} "
          f"{'reduction':>10}")
    flat = []
    for name, m in doc["axes"].items():
        pct = m["reduction_pct"]
        if pct is None:
            flat.append(name)
        print(f"{name:<10} {m['rmse_um']:>9.3f} {m['max_abs_um']:>10.3f} {m['raw_rms_um']:>11.3f} "
              f"{m['raw_peak_um']:>12.3f} "
              + (f"{'-':>10}" if pct is None else f"{pct:>9.1f}%"))
    if flat:
        print(f"({', '.join(flat)}: no drift measured, the column is constant: a reduction is "
              "undefined; the rmse is what the model adds)")
    if any(unit_of(name) != "um" for name in doc["axes"]):
        print("(a tilt axis, *_urad, is in urad)")
    if readings is not None:
        print(f"probes ({readings.source}):")
        print(f"{'axis':<10} {'updated':>9} {'static':>9} {'probe-only':>11} {'probes':>7} "
              f"{'refused':>8}")
        for name, m in doc["axes"].items():
            print(f"{name:<10} {m['rmse_um']:>9.3f} {m['static_rmse_um']:>9.3f} "
                  f"{m['probe_only_rmse_um']:>11.3f} {m['probes']:>7} {m['refused']:>8}")
    for line in describe(doc["outside_training_range"], input_units(model)):
        print(line)
    return 0

"""`host report MODEL --runs A.csv B.csv -o report/`: the HTML report with its figures."""

from __future__ import annotations

import argparse
import json

from thermal_comp.contract.tilt import unit_text
from thermal_comp.host.commands._arguments import add_reference_argument
from thermal_comp.host.commands._options import add_fill_gaps, csv_format
from thermal_comp.host.commands._probes import add_probe_arguments, probe_plan

NAME = "report"
HELP = "write an HTML report (with PNG figures) of a model on runs, its peers and effects"


def register(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", help="model.json written by `host train` (or `host codegen`)")
    parser.add_argument("--runs", nargs="+", required=True, metavar="CSV",
                        help="runs to show (training runs and unseen ones)")
    parser.add_argument("-o", "--out", default="report", help="output folder (default: report)")
    parser.add_argument("--protocols", metavar="FILE",
                        help="`host compare-protocols` results (JSON or CSV) for the heat map")
    parser.add_argument("--hil", nargs="+", metavar="JSON", default=[],
                        help="`python -m thermal_comp.hil replay --json` results to show the box's "
                        "own output")
    parser.add_argument("--no-peers", action="store_true",
                        help="do not fit the peer models of `host compare`")
    add_fill_gaps(parser)
    add_reference_argument(parser, training=False)
    parser.add_argument("--locations", metavar="CSV",
                        help="where each thermocouple sits on the machine, for the wiring sheet "
                        "(columns sensor, location)")
    parser.add_argument("--json", action="store_true",
                        help="print the summary as JSON instead of text")
    add_probe_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from thermal_comp.host.analysis.report import build_report

    report = build_report(args.model, args.runs, args.out, protocols=args.protocols,
                          peers=not args.no_peers, fill_gaps=args.fill_gaps, quiet=args.json,
                          hil=args.hil, fmt=csv_format(args), reference=args.reference,
                          locations=args.locations, probes=probe_plan(args))
    if args.json:
        print(json.dumps({"index": str(report.index), **report.summary}, indent=2))
        return 0
    print(f"report: {report.index} ({len(report.figures)} figures)")
    for row in report.summary["axes"]:
        val, raw = row["validation_rmse_um"], row["raw_rms_um"]
        if val is not None and raw:
            u = unit_text(row["axis"])
            print(f"  {row['axis']}: {', '.join(row['sensors'])}; validation RMSE {val:.2f} {u} "
                  f"of {raw:.2f} {u} raw ({row['reduction_pct']:.1f} % less)")
    for run_name, s in report.summary.get("service", {}).items():
        print(f"  in service on {run_name} ({s['probes']}):")
        for axis, m in s["axes"].items():
            print(f"    {axis}: updated {m['rmse_um']:.3f}, static {m['static_rmse_um']:.3f}, "
                  f"probe-only {m['probe_only_rmse_um']:.3f} ({m['probes']} readings, "
                  f"{m['refused']} refused)")
    return 0

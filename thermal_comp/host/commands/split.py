"""`host split RUN.csv --at-hours 24 -o build/`: cut a run into consecutive time windows."""

from __future__ import annotations

import argparse
import json

from thermal_comp.host.commands._options import add_format_arguments, csv_format
from thermal_comp.host.io import split_file

NAME = "split"
HELP = "cut a run into consecutive parts at given hours (e.g. train/test cycles)"


def register(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", metavar="RUN.csv")
    parser.add_argument("--at-hours", type=float, action="append", required=True, metavar="H",
                        help="cut at this time_s (hours); repeat for several cuts")
    parser.add_argument("-o", "--out", default="build", metavar="DIR",
                        help="output directory (default %(default)s)")
    add_format_arguments(parser)
    parser.add_argument("--json", action="store_true", help="print the written paths as JSON")


def run(args: argparse.Namespace) -> int:
    paths = split_file(args.run, [h * 3600.0 for h in args.at_hours], args.out,
                       fmt=csv_format(args))
    if args.json:
        print(json.dumps({"parts": [str(p) for p in paths]}))
    else:
        for p in paths:
            print(p)
    return 0

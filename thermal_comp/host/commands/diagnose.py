"""`host diagnose MODEL.json RUN.csv [--json]`: a model on a new run -- its error, which effect
explains what remains, and which sensors look faulty. Nothing is refitted."""

from __future__ import annotations

import argparse
import json

from thermal_comp.contract.errors import InputError
from thermal_comp.contract.model_file import jsonable, read_model
from thermal_comp.host.analysis import diagnose, load_for_diagnosis, summary_lines
from thermal_comp.host.commands._arguments import add_reference_argument
from thermal_comp.host.commands._options import add_fill_gaps, csv_format
from thermal_comp.host.fitting import DEFAULT_BLOCKS
from thermal_comp.host.train import input_units

NAME = "diagnose"
HELP = ("a model on a new run: its error, the candidate effect that explains what remains, and "
        "sensors that drift from their cluster-mates, stick or are noisy")


def register(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", metavar="MODEL.json", help="model.json written by host train")
    parser.add_argument("run", metavar="RUN.csv", help="a run with the model's sensors (all "
                        "sensors of the training glob are used as cluster-mates)")
    parser.add_argument("--ambient", metavar="COL", default=None,
                        help="ambient temperature column (default: a sensor named like *amb*)")
    parser.add_argument("--blocks", type=int, default=DEFAULT_BLOCKS, metavar="N",
                        help="time blocks of the run that validate an effect (default "
                        "%(default)s)")
    add_reference_argument(parser, training=False)
    add_fill_gaps(parser)
    parser.add_argument("--json", action="store_true", help="print JSON on stdout")


def run(args: argparse.Namespace) -> int:
    if args.blocks < 2:
        raise InputError(f"--blocks must be >= 2 (got {args.blocks})")
    model = read_model(args.model)
    data = load_for_diagnosis(model, args.run, args.fill_gaps, csv_format(args))
    doc = {"model": args.model, **diagnose(model, data, ambient=args.ambient,
                                           n_blocks=args.blocks, reference=args.reference)}
    if args.json:
        print(json.dumps(jsonable(doc), indent=2, allow_nan=False))
    else:
        print(f"model: {args.model}")
        print("\n".join(summary_lines(doc, input_units(model))))
    return 0

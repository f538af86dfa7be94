"""`host codegen`: model.json -> fixed-point C header with a proven error bound."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

NAME = "codegen"
HELP = "generate the firmware's fixed-point model header (model.h) from a model.json"


def register(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", type=Path, help="model.json written by `host train`")
    parser.add_argument("-o", "--output", type=Path, default=None,
                        help="header to write (default: model.h next to the model.json)")
    parser.add_argument("--max-error-um", type=float, default=None,
                        help="refuse if any axis's worst-case fixed-point error exceeds this "
                             "(um, default 0.01)")
    parser.add_argument("--zero-at-powerup", action=argparse.BooleanOptionalAction,
                        default=None,
                        help="the box behaves as if ZERO was received before its first sample: "
                             "every correction is the change since power-up (TCM_ZERO_AT_POWERUP, "
                             "docs/protocol.md); default: on for a model with the start "
                             "reference (host train --reference start), off for none")
    parser.add_argument("--json", action="store_true",
                        help="print the fixed_point block as JSON instead of a summary")


def run(args: argparse.Namespace) -> int:
    from thermal_comp import codegen

    max_error = codegen.DEFAULT_MAX_ERROR_UM if args.max_error_um is None else args.max_error_um
    out = args.output or args.model.with_name("model.h")
    try:
        block = codegen.write_header(args.model, out, max_error_um=max_error,
                                     zero_at_powerup=args.zero_at_powerup).fixed_point
    except codegen.BoundError as exc:  # a failed check, not bad input: exit 1 (host/cli.py)
        print(f"host codegen: check failed: {exc}", file=sys.stderr)
        return 1
    from thermal_comp.contract.model_file import read_model, stored_hashes

    if not stored_hashes(read_model(args.model)):
        print(f"host codegen: note: {args.model} carries no model_hash (hand-written, or older "
              "than the key): there was nothing to check its content against", file=sys.stderr)
    if args.json:
        print(json.dumps(block, indent=2))
        return 0
    print(f"{out}: model {block['model_hash']}, CRC-32 {block['crc32']}, "
          f"{len(block['channels'])} channel(s), {len(block['axes'])} axis/axes"
          + (", ZERO at power-up" if block["zero_at_powerup"] else ""))
    defaults = [c["sensor"] for c in block["channels"] if c["max_step_source"] == "default"]
    defaults += [name for name, ax in block["axes"].items() if ax["max_step_source"] == "default"]
    for name, ax in block["axes"].items():
        print(f"  {name}: shift {ax['shift']}, {len(ax['terms'])} term(s), error bound "
              f"{ax['bound_um']:.6f} um (limit {max_error:g}; input quantisation "
              f"{ax['input_quantisation_um']:.6f} um reported separately), output step limit "
              f"{ax['max_step_nm'] / 1000:g} um per sample")
    if defaults:
        print(f"  step limits: conservative defaults for {', '.join(defaults)} (the model.json "
              "has no max_step_c / max_step_um: retrain with this host to derive them from "
              "the training runs; docs/codegen.md)")
    return 0

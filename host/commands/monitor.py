"""`host monitor PORT [--model build/model.json] [--log run.csv]`: watch a box live.

The reading and the state live in host.box.monitor; what is shown is chosen here: the
full-screen terminal view (curses) on a terminal or with --screen, one line per sample with
--plain or when stdout is not a terminal (a pipe, a file), one JSON object per line with
--json."""

from __future__ import annotations

import argparse

NAME = "monitor"
HELP = "show a box's live corrections, temperatures and status flags; check its model hash"


def register(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("port", help="serial port (/dev/ttyUSB0, the HIL's pty, or a pyserial "
                        "URL such as socket://host:port)")
    parser.add_argument("--baud", type=int, default=115200, help="baud rate (default 115200)")
    parser.add_argument("--model", metavar="JSON",
                        help="model.json whose hash the box must report (checked via INFO); "
                        "also names the channels behind an EXTRAP flag and the axes a faulted "
                        "channel holds")
    parser.add_argument("--log", metavar="CSV", help="append every sample received to this CSV "
                        "(a faulted channel's cell is left empty, its fault in the 'faults' "
                        "column)")
    parser.add_argument("--count", type=int, metavar="N", help="stop after N samples")
    parser.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    parser.add_argument("--retry", type=float, default=1.0, metavar="S",
                        help="seconds between reconnection attempts (default 1)")
    display = parser.add_mutually_exclusive_group()
    display.add_argument("--json", action="store_true",
                         help="one JSON object per line: every sample (corrections in µm, "
                         "temperatures in °C, null for a faulted channel, flags, faulted "
                         "channels, held axes), every event, and a closing summary")
    display.add_argument("--plain", action="store_true",
                         help="one line per sample (and per event, per fault and its clearing) "
                         "even on a terminal; the default when stdout is not a terminal")
    display.add_argument("--screen", "--ansi", dest="screen", action="store_true",
                         help="the full-screen view (curses: live values, fault history, "
                         "events; q quits) even when stdout is not known to be a terminal; "
                         "the default on a terminal")


def run(args: argparse.Namespace) -> int:
    from host.box import Monitor, MonitorError  # pyserial: the [monitor] extra

    expected, windows, axis_inputs, promises = None, {}, {}, {}
    if args.model:
        from codegen import generate, model_hash
        from contract.model_file import read_model
        from contract.terms import TEMPERATURE_KINDS

        model = read_model(args.model)
        expected = model_hash(model)
        windows = {c.sensor: (c.window_lo_code, c.window_hi_code)
                   for c in generate(model).model.channels}
        # which thermocouples each axis reads: a fault on one of them holds that axis
        axis_inputs = {a: sorted({t["source"] for t in ax["terms"]
                                  if t["kind"] in TEMPERATURE_KINDS})
                       for a, ax in model["axes"].items()}
        # the model's promise per axis, in the words host train and the report use
        promises = {a: ax.get("metrics", {}).get("promise") for a, ax in model["axes"].items()
                    if ax.get("metrics", {}).get("promise")}
    if args.count is not None and args.count < 1:
        raise MonitorError(f"--count must be at least 1 (got {args.count})")
    if args.duration is not None and args.duration <= 0:
        raise MonitorError(f"--duration must be positive (got {args.duration})")
    screen = True if args.screen else False if args.plain else None
    monitor = Monitor(args.port, args.baud, expected_hash=expected, windows=windows, log=args.log,
                      count=args.count, duration=args.duration, screen=screen, retry_s=args.retry,
                      axis_inputs=axis_inputs, json_lines=args.json, promises=promises)
    return monitor.run()

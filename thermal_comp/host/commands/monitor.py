"""`host monitor PORT [--model build/model.json] [--log run.csv]`: watch a box live.

The reading lives in host.box.monitor, the state in host.box.state; what is shown is chosen
here: the full-screen terminal view (curses) on a terminal or with --screen, one line per
sample with --plain or when stdout is not a terminal (a pipe, a file), one JSON object per line
with --json. With --mqtt URL --machine NAME the box's lines also go to the fleet's broker, through
the same relay as ``host gateway`` (host.fleet.gateway.BoxRelay: the same messages, the same
spool), while the screen shows them (docs/fleet.md)."""

from __future__ import annotations

import argparse
import logging

from thermal_comp.host.commands.gateway import add_spool_options, open_spool

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
    fleet = parser.add_argument_group("fleet (docs/fleet.md)")
    fleet.add_argument("--mqtt", metavar="URL",
                       help="also publish the box's state to this MQTT broker, as `host "
                       "gateway` does (mqtt://[user[:password]@]host[:port] or mqtts://...; "
                       "needs --machine); no command is taken from the broker")
    fleet.add_argument("--machine", metavar="NAME",
                       help="the machine's name on the broker: thermalcomp/NAME/...")
    add_spool_options(fleet)
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
    from thermal_comp.host.box import Monitor, MonitorError  # pyserial: the [monitor] extra

    expected, windows, axis_inputs, promises = None, {}, {}, {}
    if args.model:
        from thermal_comp.codegen import generate
        from thermal_comp.contract.model_file import check_model, read_model

        model = read_model(args.model)  # its metrics too: the promises
        spec = check_model(model, args.model)
        expected = spec.model_hash
        windows = {c.sensor: (c.window_lo_code, c.window_hi_code)
                   for c in generate(spec).model.channels}
        # which thermocouples each axis reads: a fault on one of them holds that axis
        axis_inputs = {ax.name: sorted(ax.sensors) for ax in spec.axes}
        # the model's promise per axis (a report field, in the dict), in the words host train
        # and the report use
        promises = {a: ax.get("metrics", {}).get("promise") for a, ax in model["axes"].items()
                    if ax.get("metrics", {}).get("promise")}
    if args.count is not None and args.count < 1:
        raise MonitorError(f"--count must be at least 1 (got {args.count})")
    if args.duration is not None and args.duration <= 0:
        raise MonitorError(f"--duration must be positive (got {args.duration})")
    if bool(args.mqtt) != bool(args.machine):
        raise MonitorError("--mqtt and --machine go together: the broker's URL and the name "
                           "this box's topics are published under")
    if (args.spool or args.no_spool) and not args.mqtt:
        raise MonitorError("--spool/--no-spool keep what goes to the broker: give --mqtt too")
    views = []
    if args.mqtt:
        from thermal_comp.host.fleet.gateway import BoxRelay  # paho-mqtt: the [fleet] extra

        views.append(BoxRelay(args.mqtt, args.machine, spool=open_spool(args)))
    screen = True if args.screen else False if args.plain else None
    monitor = Monitor(args.port, args.baud, expected_hash=expected, windows=windows, log=args.log,
                      count=args.count, duration=args.duration, screen=screen, retry_s=args.retry,
                      axis_inputs=axis_inputs, json_lines=args.json, promises=promises,
                      views=views)
    if views:  # the relay's news (broker lost, spool recovered) among the monitor's events
        _log_to(monitor)
    return monitor.run()


class _ToMonitor(logging.Handler):
    def __init__(self, monitor) -> None:
        super().__init__(logging.INFO)
        self.monitor = monitor

    def emit(self, record: logging.LogRecord) -> None:
        try:
            self.monitor.note(f"mqtt: {record.getMessage()}", kind="mqtt")
        except Exception:  # noqa: BLE001 (a log line must never stop the monitor)
            self.handleError(record)


def _log_to(monitor) -> None:
    """The fleet code's log (host.fleet.*) shown as monitor events, not on stderr where
    it would tear the screen."""
    fleet = logging.getLogger("thermal_comp.host.fleet")
    fleet.setLevel(logging.INFO)
    fleet.propagate = False
    fleet.addHandler(_ToMonitor(monitor))

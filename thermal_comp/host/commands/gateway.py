"""`host gateway PORT --mqtt URL --machine NAME`: one box to the fleet's broker, headless."""

from __future__ import annotations

import argparse
import logging

NAME = "gateway"
HELP = ("publish one box's state (sample, flags, corrections, temperatures, faults, probe "
        "residuals, model hash) to an MQTT broker: headless, run one per box as a service")


def register(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("port", help="serial port (/dev/ttyUSB0, the HIL's pty, or a pyserial "
                        "URL such as socket://host:port)")
    parser.add_argument("--mqtt", required=True, metavar="URL",
                        help="broker: mqtt://[user[:password]@]host[:port] or mqtts://... "
                        "(?ca=ca.pem for a private CA); the password may come from "
                        "$THERMALCOMP_MQTT_PASSWORD (docs/fleet.md)")
    parser.add_argument("--machine", required=True, metavar="NAME",
                        help="the machine's name: its topics are thermalcomp/NAME/...")
    parser.add_argument("--baud", type=int, default=115200, help="baud rate (default 115200)")
    parser.add_argument("--allow-commands", metavar="USER,...", default="",
                        help="take ZERO/STATUS/INFO/RATE from these broker users on "
                        "thermalcomp/NAME/cmd/<user> (default: no command is taken; a remote "
                        "ZERO moves a tool); needs an authenticated connection")
    add_spool_options(parser)
    parser.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    parser.add_argument("--count", type=int, metavar="N", help="stop after N samples")
    parser.add_argument("-v", "--verbose", action="store_true", help="log every connection")


def add_spool_options(parser: argparse.ArgumentParser) -> None:
    """--spool / --no-spool, shared with ``host monitor --mqtt``."""
    spool = parser.add_mutually_exclusive_group()
    spool.add_argument("--spool", metavar="PATH",
                       help="keep every message on disk until the broker acknowledges it, and "
                       "publish what an earlier run left there first: a gateway killed during "
                       "a broker outage loses nothing (default: "
                       "$XDG_STATE_HOME/thermalcomp/spool-NAME.jsonl, i.e. "
                       "~/.local/state/thermalcomp/spool-NAME.jsonl)")
    spool.add_argument("--no-spool", action="store_true",
                       help="no spool: unacknowledged messages live only in memory")


def open_spool(args: argparse.Namespace):
    """The spool the options ask for (None with --no-spool)."""
    from thermal_comp.host.fleet.spool import Spool, default_spool_path
    from thermal_comp.host.fleet.topics import check_machine

    if args.no_spool:
        return None
    return Spool(args.spool or default_spool_path(check_machine(args.machine)))


def run(args: argparse.Namespace) -> int:
    from thermal_comp.host.fleet.gateway import Gateway

    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    users = frozenset(u.strip() for u in args.allow_commands.split(",") if u.strip())
    gateway = Gateway(args.port, args.mqtt, args.machine, baud=args.baud, allow_users=users,
                      spool=open_spool(args))
    return gateway.run(duration=args.duration, count=args.count)

"""``python -m thermal_comp.hil replay --model build/model.json --data RUN.csv [--json]``.

Exit codes as ``host``: 0 every check passed, 1 a check failed, 2 bad input or the replay
could not be carried out (no firmware, build error, box did not start).
"""

from __future__ import annotations

import argparse
import json
import sys

from thermal_comp.contract.tilt import unit_of
from thermal_comp.hil.box_csv import write_box_csv
from thermal_comp.hil.build import BuildError, firmware_dir
from thermal_comp.hil.checks import Judging, ReplayReport
from thermal_comp.hil.link import LinkTimeout
from thermal_comp.hil.native import BoxStartError
from thermal_comp.host.fitting import REFERENCE_KINDS


def _fmt(value: float | None, digits: int = 3) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def _int(value: int | None) -> str:
    return "-" if value is None else str(value)


def format_table(report: ReplayReport, data: str) -> str:
    """The human-readable replay summary."""
    rate = (f", {report.samples / report.elapsed_s:,.0f} samples/s"
            if report.elapsed_s else "")
    lines = [f"HIL replay of {data}: {report.samples} samples, {report.received} lines "
             f"received{rate}", ""]
    lines += axis_lines(report)
    lines += format_service(report)
    lines.append("")
    checks = {k: "PASS" if v else "FAIL" for k, v in report.checks.items()}
    lines.append(f"1. firmware = twin, bit for bit   {checks['twin_bit_exact']}"
                 f"  ({report.mismatches} correction, {report.status_mismatches} status, "
                 f"{report.code_mismatches} code mismatches)")
    lines.append(f"2. float model within bound       {checks['float_within_bound']}")
    lines.append(f"3. no lost/duplicated/reordered   {checks['no_lost_duplicated_reordered']}"
                 f"  ({report.lost} lost, {report.duplicated} duplicated, {report.reordered} "
                 f"reordered, {report.bad_lines} bad lines)")
    lines.append("4. residuals                      reported above (measured - correction)")
    if report.judging is not None:
        lines += judged_lines(report)
    if report.status_counts:
        lines.append("   status bits the box raised (samples): " + ", ".join(
            f"{k} {v}" for k, v in report.status_counts.items())
            + ("  (EXTRAP: inputs beyond the training window; still corrected)"
               if "EXTRAP" in report.status_counts else ""))
    if "qemu_equals_native" in checks:
        lines.append(f"5. QEMU image = native build      {checks['qemu_equals_native']}"
                     "  (every sample line byte for byte)")
    if report.problems:
        lines += ["", "problems:"] + [f"  {p}" for p in report.problems]
    lines += ["", "RESULT: " + ("PASS" if report.ok else "FAIL")]
    return "\n".join(lines)


def axis_lines(report: ReplayReport) -> list[str]:
    """The per-axis table: raw and compensated error, the twin's and the float model's
    differences from the firmware, the proven bound; a tilt axis in its own unit."""
    head = (f"{'axis':<10} {'raw rms':>9} {'raw peak':>9} {'comp rms':>9} {'comp peak':>10} "
            f"{'twin diff':>10} {'float diff':>11} {'bound':>9}")
    units = ("um (urad for a tilt axis)" if any(unit_of(a) == "urad" for a in report.axes)
             else "um")
    lines = [head, f"{'':<10} {'um':>9} {'um':>9} {'um':>9} {'um':>10} {'nm':>10} "
             f"{'um':>11} {'um':>9}" if units == "um" else
             f"{'':<10} in each axis's unit: {units}; twin diff in thousandths of it",
             "-" * len(head)]
    for name, a in report.axes.items():
        lines.append(f"{name:<10} {_fmt(a.raw_rms_um):>9} {_fmt(a.raw_peak_um):>9} "
                     f"{_fmt(a.compensated_rms_um):>9} {_fmt(a.compensated_peak_um):>10} "
                     f"{a.max_abs_diff_nm:>10d} {_fmt(a.float_max_diff_um, 6):>11} "
                     f"{_fmt(a.bound_um, 6):>9}")
    return lines


def judged_lines(report: ReplayReport) -> list[str]:
    """Checks 6-8, the replay judged (``Judging``: ``--max-held-fraction`` and its kin): held,
    limited and clamped shares, no worse than uncompensated, the output steps."""
    j, jm = report.judging, report.judgement
    first = ("held_within_limit", "limited_within_limit", "clamped_within_limit",
             "corrected")
    lines = [f"6. held, limited, clamped         "
             f"{'PASS' if all(jm.get(k, True) for k in first) else 'FAIL'}"
             f"  (held {100 * report.held_fraction:.1f} % <= "
             f"{100 * j.max_held_fraction:g} %, limited "
             f"{100 * report.limited_fraction:.1f} % <= "
             f"{100 * j.max_limited_fraction:g} %, clamped "
             f"{100 * report.clamped_fraction:.1f} % <= "
             f"{100 * j.max_clamped_fraction:g} %, corrected on "
             f"{report.corrected_samples} samples)"]
    if "no_worse_than_uncompensated" in jm:
        worse = report.worse_axes
        lines.append(f"7. no worse than uncompensated    "
                     f"{'PASS' if jm['no_worse_than_uncompensated'] else 'FAIL'}"
                     + (f"  (worse: {', '.join(worse)})" if worse else
                        "  (compensated RMS and peak <= raw on every measured axis)"))
    if "steps_within_limit" in jm:
        steps = ", ".join(f"{name} {_int(a.largest_step_nm)} <= {_int(a.max_step_nm)}"
                          for name, a in report.axes.items())
        lines.append(f"8. output steps within limit      "
                     f"{'PASS' if jm['steps_within_limit'] else 'FAIL'}"
                     f"  (largest step nm: {steps})")
    return lines


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m thermal_comp.hil",
        description="Hardware-in-the-loop: replay recorded runs through the real firmware "
        "(native build over a pty, or QEMU) and check it against the host.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    p = sub.add_parser("replay", help="replay a run through the firmware and check every line",
                       description="Build the firmware with the model's header, feed every "
                       "sample of the run, and check the box against the integer twin, the "
                       "float model and its own sequence numbers.")
    p.add_argument("--model", required=True, help="model.json (header generated if needed)")
    p.add_argument("--data", required=True, help="run CSV to replay")
    p.add_argument("--json", action="store_true", help="print the result as JSON, no progress")
    p.add_argument("--build-dir", default=None,
                   help="where headers and firmware builds go (default: <model dir>/hil)")
    p.add_argument("--box-cflags", default="",
                   help="extra -D options for the firmware build (e.g. -DBOX_SLEW_NM_PER_S=500)")
    p.add_argument("--firmware", default=None,
                   help="use this prebuilt native binary instead of building one")
    p.add_argument("--window", type=int, default=256,
                   help="samples in flight between feed and answer (default 256)")
    p.add_argument("--target", choices=["native", "qemu"], default="native",
                   help="native build over a pty (default) or the STM32F405 image in QEMU")
    p.add_argument("--out", default=None, metavar="BOX.csv",
                   help="write what the box sent for every sample: time_s, session, seq, "
                        "status (hex and names), each axis's correction in um")
    p.add_argument("--zero-at", type=int, action="append", default=[], metavar="SAMPLE",
                   help="send ZERO before this sample (repeatable); the twin follows")
    p.add_argument("--zero-at-powerup", action=argparse.BooleanOptionalAction, default=None,
                   help="build the header with TCM_ZERO_AT_POWERUP (as host codegen "
                        "--zero-at-powerup; default: on for a model with the start reference)")
    p.add_argument("--reference", choices=REFERENCE_KINDS, default=None,
                   help="judge the run by its change since the start (start) or against one "
                        "fixed datum (none), and zero the box at power-up to match "
                        "(default: the model's reference)")
    g = p.add_argument_group(
        "probe readings (issue 42)", "a touch probe's readings sent as MEAS <axis> <nm> <seq> "
        "after the sample they read; the box's $M replies and shifted outputs are checked "
        "against codegen.estimator. Without --probe-every a run's logged probe_<axis> columns "
        "are used as they are")
    g.add_argument("--probe-every", default=None, metavar="DURATION",
                   help="synthesise a reading every DURATION (30min, 2h, 900s) from the run's "
                        "measured displacement")
    g.add_argument("--probe-noise-um", type=float, default=0.5,
                   help="the synthesised readings' noise, um (default 0.5)")
    g.add_argument("--probe-seed", type=int, default=0, help="their noise seed (default 0)")
    g.add_argument("--probe-when", choices=("interval", "stopped"), default="interval",
                   help="on the clock, or only while the spindle stands (default interval)")
    d = Judging()
    p.add_argument("--max-held-fraction", type=float, default=d.max_held_fraction,
                   help="fail when more than this share of the samples held (HOLD/NO_DATA; "
                        f"default {d.max_held_fraction:g})")
    p.add_argument("--max-limited-fraction", type=float, default=d.max_limited_fraction,
                   help="fail when more than this share of the samples had their output "
                        f"step limited (SLEW; default {d.max_limited_fraction:g})")
    p.add_argument("--max-clamped-fraction", type=float, default=d.max_clamped_fraction,
                   help="fail when more than this share of the samples were clamped to the "
                        f"box's maximum correction (CLAMP; default {d.max_clamped_fraction:g})")
    return parser


def cmd_replay(args: argparse.Namespace) -> int:
    from thermal_comp.hil import replay as hil_replay
    from thermal_comp.hil.runner import Zero

    for name in ("max_held_fraction", "max_limited_fraction", "max_clamped_fraction"):
        v = getattr(args, name)
        if not 0.0 <= v <= 1.0:
            raise ValueError(f"--{name.replace('_', '-')} {v:g} must be between 0 and 1")
    firmware_dir()  # the box's sources and box_config.h are the checkout's: say so first
    setup = hil_replay.prepare(args.model, args.data, args.build_dir, args.box_cflags,
                               args.firmware, zero_at_powerup=args.zero_at_powerup,
                               reference=args.reference)
    n = setup.feed.n_samples
    bad = [z for z in args.zero_at if not 0 <= z < n]
    if bad:
        raise ValueError(f"--zero-at {bad[0]}: the run has samples 0..{n - 1}")
    setup.judging = Judging(args.max_held_fraction, args.max_limited_fraction,
                            max_clamped_fraction=args.max_clamped_fraction)
    events: list = [Zero(z) for z in sorted(set(args.zero_at))]
    events += probe_events(setup, args)
    if args.target == "qemu":
        from thermal_comp.hil import qemu
        from thermal_comp.hil.capture_compare import capture_differences

        start_box = qemu.box_factory(setup, args.build_dir, args.box_cflags)
        report, capture = hil_replay.run(setup, events, quiet=args.json, window=args.window,
                                         start_box=start_box)
        # The emulated STM32F405 must send exactly what the native build sends.
        _, native = hil_replay.run(setup, events, quiet=True, window=args.window)
        differing, first = capture_differences(capture, native)
        report.extra_checks["qemu_equals_native"] = differing == 0
        if differing:
            report.note(f"QEMU vs native: {differing} sample lines differ; first: {first}")
    else:
        report, _ = hil_replay.run(setup, events, quiet=args.json, window=args.window)
    if args.out:
        write_box_csv(report, setup.feed, args.out)
    if args.json:
        doc = {**report.to_json(), "data": args.data, "model": args.model,
               "target": args.target}
        print(json.dumps(doc, indent=2))
    else:
        print(format_table(report, args.data))
    return 0 if report.ok else 1


def probe_events(setup, args: argparse.Namespace) -> list:
    """MEAS events from synthesised (--probe-every) or logged (probe_<axis>) readings: the
    reading of sample k goes to the box after k's line, before sample k + 1."""
    from thermal_comp.codegen.estimator import to_nm
    from thermal_comp.hil.runner import Meas
    from thermal_comp.host.service.probes import (
        ProbePlan,
        any_logged,
        duration_s,
        logged_probes,
        synthesise_probes,
    )

    feed = setup.feed
    if args.probe_every is not None:
        plan = ProbePlan(duration_s(args.probe_every), args.probe_noise_um, args.probe_seed,
                         args.probe_when)
        readings = synthesise_probes(feed.run, feed.measured, plan)
    elif any_logged(args.data, feed.axes):
        readings = logged_probes(args.data, feed.run, feed.axes)
    else:
        return []
    events = []
    for axis, idx in readings.index.items():
        a = feed.axes.index(axis)
        for k, v in zip(idx.tolist(), readings.value[axis].tolist(), strict=True):
            if k + 1 < feed.n_samples:
                events.append(Meas(k + 1, a, to_nm(v), k))
    return sorted(events, key=lambda e: (e.at, e.axis))


def format_service(report: ReplayReport) -> list[str]:
    """Per axis: static and updated RMS, readings applied and refused (issue 42)."""
    if not report.service:
        return []
    lines = ["", f"{'axis':<10} {'static rms':>11} {'updated rms':>12} {'probes':>7} "
             f"{'applied':>8}  refused"]
    for name, v in report.service.items():
        refused = ", ".join(f"{k} {n}" for k, n in v["refused"].items()) or "-"
        lines.append(f"{name:<10} {v['static_rmse_um']:>11.3f} {v['updated_rmse_um']:>12.3f} "
                     f"{v['probes']:>7d} {v['applied']:>8d}  {refused}")
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return cmd_replay(args)
    except (ValueError, KeyError, FileNotFoundError, BuildError, BoxStartError,
            LinkTimeout) as exc:
        msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else str(exc)
        print(f"hil {args.command}: error: {msg}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"hil {args.command}: interrupted", file=sys.stderr)
        return 130

"""`make demo`: from nothing to a compensating box, a replay and a report, with real data too.

Every step runs the real command line (``host ...``, ``make -C firmware``, ``python -m
thermal_comp.hil``) in a subprocess, exactly what a user would type, so the demo exercises the
product rather than a shortcut through its internals. Each step prints a header and its key
numbers; the first step that fails stops the demo with its command, the tail of its output and exit
code 1.

The story:
  1. example runs (simulated constant/step/random spindle protocols; made only if missing)
  2. train on constant + step: the sensors chosen per axis and the validation error
  3. the fixed-point C header and its error bound
  4. firmware for the STM32F405 (flash/RAM) and for the native board
  5. HIL: the native firmware replays the unseen random run over a pty, checked against the host
  6. protocol comparison (which test protocol to run) and the report
  7. real data (FL_THERMAL): train on the first three heat/cool cycles (0-24 h), judge on the
     fourth (24-32 h, 5000 rpm, a speed never seen in training), and its report
  8. where the reports are, and the error before/after compensation on every run
"""

from __future__ import annotations

import json
import os
import shlex
import subprocess
import sys
import textwrap
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

from thermal_comp.contract import checkout
from thermal_comp.host.demo_baseline import why_worse_than_baseline, worse_than_baseline
from thermal_comp.host.train import dropped_reason, ridge_lags_note

ROOT = checkout.root()
EXAMPLES = Path("examples")
BUILD = Path("build")
REPORT = Path("report")
SIM_TRAIN = [EXAMPLES / "sim_constant.csv", EXAMPLES / "sim_step.csv"]
SIM_TEST = EXAMPLES / "sim_random.csv"
SIM_TARGETS = ["dx_um", "dy_um", "dz_um"]
FL_RUN = EXAMPLES / "fl_thermal_steps.csv"
FL_SPLIT_H = 24.0  # three 8 h heat/cool cycles for training, the fourth (5000 rpm) for judging
FL_TARGETS = ["ch1_um", "ch2_um", "ch3_um", "ch4_um", "ch5_um"]
FL_BUILD = BUILD / "fl"
FL_REPORT = REPORT / "fl"
HIL_RESULT = BUILD / f"hil_{SIM_TEST.stem}.json"
FL_HIL_RESULT = FL_BUILD / "hil_fl_24-32h.json"
STEP_TIMEOUT_S = 600


class DemoFailed(RuntimeError):
    """A step failed; the message says which, with the command and its output's tail."""


class Demo:
    def __init__(self, out=None) -> None:
        self.out = out or sys.stdout
        self.step_no = 0
        self.started = time.monotonic()
        self.step_started = self.started
        self.current = ""

    # ---- printing ------------------------------------------------------------------------
    def say(self, text: str = "") -> None:
        print(text, file=self.out, flush=True)

    def step(self, title: str) -> None:
        self.step_no += 1
        self.current = title
        self.step_started = time.monotonic()
        self.say(f"\n==> [{self.step_no}] {title}")

    def done(self) -> None:
        self.say(f"    ({time.monotonic() - self.step_started:.1f} s)")

    # ---- running -------------------------------------------------------------------------
    def run(self, args: Sequence[str | Path], what: str | None = None,
            timeout: float = STEP_TIMEOUT_S) -> str:
        """Run one command from the project root; its stdout, or DemoFailed with the output."""
        cmd = [str(a) for a in args]
        shown = " ".join(shlex.quote(c) for c in cmd).replace(str(ROOT) + "/", "")
        self.say(f"    $ {shown}")
        env = dict(os.environ)
        env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
        try:
            done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True,
                                  timeout=timeout, env=env)
        except FileNotFoundError as exc:
            raise DemoFailed(f"{what or self.current}: cannot run {cmd[0]}: {exc}") from None
        except subprocess.TimeoutExpired:
            raise DemoFailed(f"{what or self.current}: `{shown}` did not finish within "
                             f"{timeout:g} s") from None
        if done.returncode != 0:
            tail = "\n".join((done.stdout + "\n" + done.stderr).strip().splitlines()[-25:])
            raise DemoFailed(f"{what or self.current}: `{shown}` exited with code "
                             f"{done.returncode}:\n{tail}")
        return done.stdout

    def host(self, *args: str | Path, timeout: float = STEP_TIMEOUT_S) -> str:
        return self.run([sys.executable, "-m", "thermal_comp.host", *args], timeout=timeout)

    def host_json(self, *args: str | Path, timeout: float = STEP_TIMEOUT_S) -> dict:
        text = self.host(*args, timeout=timeout)
        try:
            return json.loads(text)
        except json.JSONDecodeError as exc:
            raise DemoFailed(f"{self.current}: `host {args[0]}` printed no valid JSON "
                             f"({exc.msg}): {text[:300]!r}") from None


# ---------------------------------------------------------------- formatting helpers

def fmt_um(value: float | None, digits: int = 2) -> str:
    return "—" if value is None else f"{value:.{digits}f} µm"


def run_shape(path: Path) -> str:
    """Samples, duration and column count of a run, read from the file (a few ms)."""
    with (ROOT / path).open() as fh:
        header = fh.readline().strip().split(",")
        rows = [line for line in fh if line.strip()]
    t0 = float(rows[0].split(",")[0])
    t1 = float(rows[-1].split(",")[0])
    temps = sum(1 for h in header if h.startswith("T"))
    return (f"{len(rows)} samples over {(t1 - t0) / 3600:.1f} h, {temps} temperatures, "
            f"columns: {', '.join(h for h in header if not h.startswith('T'))}")


def print_training(demo: Demo, doc: dict, model: dict) -> None:
    for axis, row in doc["axes"].items():
        spec = model["axes"][axis]
        base = spec.get("baseline_validation_rmse_um")
        effects = [e.get("name", "?") + (" (box: its sensor's ridge lags)"
                                         if ridge_lags_note(e) else "")
                   for e in spec.get("effects", []) if not dropped_reason(e)]
        reasons: dict[str, list[str]] = {}  # one reason, said once for its effects
        for e in spec.get("effects", []):
            if dropped_reason(e):
                reasons.setdefault(dropped_reason(e), []).append(e.get("name", "?"))
        dropped = [f"{', '.join(names)} ({why})" for why, names in reasons.items()]
        line = (f"    {axis}: sensors {', '.join(row['sensors'])}; validation RMSE "
                f"{fmt_um(row['validation_rmse_um'])} of {fmt_um(row['raw_rms_um'])} raw"
                f" ({row.get('fit') or 'ols'})")
        if effects:
            line += (f"; effects {fmt_um(base)} -> {fmt_um(row.get('effects_validation_rmse_um'))}"
                     f" in least squares, added {', '.join(effects)}")
        gone = [s for s in spec.get("selection", {}).get("sensors", [])
                if s not in row["sensors"]]
        if dropped:
            line += f"; not in the box's model: {'; '.join(dropped)}"
        if gone:
            line += f"; selected but not read by the box: {', '.join(gone)}"
        demo.say(line)


def load_json(path: Path) -> dict:
    return json.loads((ROOT / path).read_text())


# ---------------------------------------------------------------- the steps

def step_examples(demo: Demo) -> None:
    demo.step("Example runs")
    missing = [p for p in [*SIM_TRAIN, SIM_TEST] if not (ROOT / p).is_file()]
    if missing:
        demo.say(f"    missing {', '.join(str(p) for p in missing)}: simulating them")
        demo.run([sys.executable, "-m", "thermal_comp.host.sim.examples", EXAMPLES])
    for path in [*SIM_TRAIN, SIM_TEST, FL_RUN]:
        demo.say(f"    {path}: {run_shape(path)}")
    demo.done()


def step_train_sim(demo: Demo) -> dict:
    demo.step("Train on the constant and step protocols (sensor selection, fit, effects)")
    targets = [a for t in SIM_TARGETS for a in ("--target", t)]
    doc = demo.host_json("train", *SIM_TRAIN, *targets, "--out", BUILD, "--json")
    model = load_json(BUILD / "model.json")
    print_training(demo, doc, model)
    demo.done()
    return model


def step_header(demo: Demo, model_dir: Path) -> dict:
    demo.step("Fixed-point C header")
    header = model_dir / "model.h"
    if not (ROOT / header).is_file():
        demo.host("codegen", model_dir / "model.json", "-o", header)
    model = load_json(model_dir / "model.json")
    demo.say(f"    {header}: {(ROOT / header).stat().st_size} bytes")
    for axis, fp in (model.get("fixed_point") or {}).get("axes", {}).items():
        demo.say(f"    {axis}: shift {fp.get('shift')}, box vs float model ≤ "
                 f"{fp.get('bound_um', float('nan')) * 1000:.2f} nm (bound), input "
                 f"quantisation {fmt_um(fp.get('input_quantisation_um'), 3)}")
    demo.done()
    return model


def step_firmware(demo: Demo, header: Path) -> Path:
    demo.step("Firmware for the STM32F405 and for the native board")
    model_arg = f"MODEL={ROOT / header}"
    demo.run(["make", "-C", "firmware", "BOARD=stm32f405", model_arg])
    elf = ROOT / "firmware" / "build" / "stm32f405" / "thermal_box.elf"
    size = demo.run(["arm-none-eabi-size", elf]).splitlines()
    if len(size) >= 2:
        text, data, bss = (int(v) for v in size[1].split()[:3])
        demo.say(f"    STM32F405 image: {text + data} bytes flash (of 1 MiB), {data + bss} bytes "
                 "static RAM (of 128 KiB)")
    demo.run(["make", "-C", "firmware", "BOARD=native", model_arg])
    native = ROOT / "firmware" / "build" / "native" / "thermal_box"
    demo.say(f"    native board: {native.relative_to(ROOT)} (UART on a pty, virtual time)")
    demo.done()
    return native


def step_hil(demo: Demo, model_json: Path = BUILD / "model.json", data: Path = SIM_TEST,
             result: Path = HIL_RESULT, title: str | None = None) -> dict:
    demo.step(title or f"HIL: the native firmware replays the unseen run {data.name}")
    text = demo.run([sys.executable, "-m", "thermal_comp.hil", "replay", "--model", model_json,
                     "--data", data, "--json"])
    try:
        doc = json.loads(text)
    except json.JSONDecodeError:
        raise DemoFailed(f"HIL replay printed no valid JSON: {text[:300]!r}") from None
    (ROOT / result).write_text(json.dumps(doc, indent=2))
    checks = doc.get("checks", {})
    demo.say(f"    {doc.get('samples')} samples fed, {doc.get('received')} lines back, "
             f"{doc.get('bad_lines')} bad, {doc.get('lost')} lost; box vs integer twin: "
             f"{doc.get('mismatches')} mismatches (max {doc.get('max_abs_diff_nm')} nm); "
             f"{doc.get('samples_per_s', 0):.0f} samples/s")
    for axis, a in doc.get("axes", {}).items():
        demo.say(f"    {axis}: box output leaves {fmt_um(a.get('compensated_rms_um'))} RMS of "
                 f"{fmt_um(a.get('raw_rms_um'))} raw; |box − float model| ≤ "
                 f"{a.get('float_max_diff_um', float('nan')) * 1000:.2f} nm "
                 f"(bound {a.get('bound_um', float('nan')) * 1000:.2f} nm)")
    failed = [name for name, ok in checks.items() if not ok]
    if not doc.get("ok", False) or failed:
        raise DemoFailed(f"HIL checks failed: {', '.join(failed) or 'not ok'}; problems: "
                         f"{doc.get('problems')}")
    demo.say(f"    checks: {', '.join(checks) or '—'}: all passed")
    extrap = doc.get("status_counts", {}).get("EXTRAP", 0)
    if extrap:
        demo.say(f"    the box raised EXTRAP on {extrap} of {doc.get('samples')} samples: "
                 "inputs beyond their training window (still corrected)")
    demo.done()
    return doc


def step_protocols(demo: Demo) -> Path | None:
    demo.step("Which test protocol to run: train on one, judge on the others (simulated days)")
    out_dir = BUILD / "protocols"
    probe = subprocess.run([sys.executable, "-m", "thermal_comp.host", "compare-protocols",
                            "--help"],
                           cwd=ROOT, capture_output=True, text=True)
    if probe.returncode != 0 and "invalid choice" in probe.stderr:
        demo.say("    skipped: this tree has no `host compare-protocols` yet")
        demo.done()
        return None
    doc = demo.host_json("compare-protocols", "--out", out_dir, "--json")
    verdict = doc.get("verdict") or {}
    scores, spread = verdict.get("scores_um", {}), verdict.get("spread_um", {})
    if scores:
        demo.say(f"    mean RMSE on the other protocols' runs over {verdict.get('repeats', 1)} "
                 "repeats (± standard deviation over the repeats):")
        demo.say("    " + ", ".join(
            f"trained on {name}: {v:.2f}" + (f" ± {spread[name]:.2f}"
                                            if spread.get(name) is not None else "") + " µm"
            for name, v in scores.items()))
        per_repeat = (doc.get("settings") or {}).get("per_repeat_ranking") or []
        if per_repeat:
            demo.say("    best per repeat: " + ", ".join(r[0] for r in per_repeat if r))
        if verdict.get("winner"):
            demo.say(f"    → the {verdict['winner']} protocol builds the model that holds best "
                     f"({verdict.get('reason')})")
        else:
            demo.say(f"    → no winner: {verdict.get('reason')}")
    demo.done()
    return out_dir / "protocols.json"


def step_report(demo: Demo, model_dir: Path, runs: list[Path], out: Path,
                protocols: Path | None = None, hil: Path | None = None) -> dict:
    demo.step(f"Report for {model_dir / 'model.json'}")
    args: list[str | Path] = ["report", model_dir / "model.json", "--runs", *runs, "-o", out,
                              "--json"]
    if protocols is not None:
        args += ["--protocols", protocols]
    if hil is not None:
        args += ["--hil", hil]
    doc = demo.host_json(*args)
    demo.say(f"    {out / 'index.html'}: {len(doc['figures'])} figures")
    demo.done()
    return doc


def step_fl(demo: Demo) -> tuple[list[Path], dict]:
    demo.step(f"Real data: split {FL_RUN.name} at {FL_SPLIT_H:g} h (3 cycles to train, "
              "the 4th to judge)")
    parts = [Path(p) for p in demo.host_json("split", FL_RUN, "--at-hours", str(FL_SPLIT_H),
                                             "-o", FL_BUILD, "--json")["parts"]]
    parts = [p.relative_to(ROOT) if p.is_absolute() else p for p in parts]
    for p in parts:
        demo.say(f"    {p}: {run_shape(p)}")
    demo.done()

    demo.step("Real data: train on the first three cycles (1250, 2500, 3750 rpm)")
    targets = [a for t in FL_TARGETS for a in ("--target", t)]
    # one continuous recording: absolute values against one datum (docs/effects.md)
    doc = demo.host_json("train", parts[0], *targets, "--aux", "spindle_rpm",
                         "--reference", "none", "--out", FL_BUILD, "--json")
    model = load_json(FL_BUILD / "model.json")
    print_training(demo, doc, model)
    demo.done()

    demo.step("Real data: judge on the fourth cycle (5000 rpm, never seen)")
    result = demo.host_json("evaluate", FL_BUILD / "model.json", parts[1], "--json")
    runs = result.get("runs", [result]) if isinstance(result, dict) else result
    for entry in runs:
        for axis, m in entry.get("axes", {}).items():
            change = m["reduction_pct"]
            verdict = ("no drift measured" if change is None else f"{change:.0f} % less"
                       if change >= 0 else f"{-change:.0f} % WORSE")
            demo.say(f"    {axis}: RMS {fmt_um(m['raw_rms_um'])} raw → {fmt_um(m['rmse_um'])} "
                     f"compensated ({verdict}), worst {fmt_um(m['max_abs_um'])}")
        beyond = entry.get("outside_training_range") or []
        if beyond:
            n_inputs = len(model["channels"]) + len(model.get("aux", []))
            demo.say(f"    hotter than training: {len(beyond)} of {n_inputs} inputs "
                     "leave their training range (" + ", ".join(
                         f"{r['input']} +{100 * r['beyond_share']:.0f} %" for r in beyond
                         if r["beyond_share"] is not None) + " of span): the model extrapolates")
    demo.done()
    return parts, model


def effects_on_box(row: dict) -> str:
    """How many of the effects the loop found the box runs ("1 of 3"), from the report's
    stages; "—" where the loop found none."""
    found = [s for s in row.get("stages_rms_um") or [] if s.get("effect")]
    if not found:
        return "—"
    return f"{sum(not s.get('dropped') for s in found)} of {len(found)}"


def print_error_table(demo: Demo, reports: list[tuple[str, dict]],
                      models: Mapping[str, dict] | None = None) -> None:
    """The closing table; every unseen row where the box's model is worse than its baseline
    is marked and explained below the table from ``models`` (label -> model.json, else the
    model.json the report names)."""
    demo.say("\nError before and after compensation (RMS over each run; 'seen' = a training run;"
             "\n'baseline' = least squares on the selected sensors' temperatures, where the loop"
             " starts;\n'box' = the model the box runs: a ridge over those sensors, their lags"
             " and the free\nchannels, with the effects it kept ('effects': kept of found)):")
    demo.say(f"    {'data':<10} {'run':<26} {'axis':<7} {'seen':<4} {'raw':>9} "
             f"{'baseline':>11} {'box':>12} {'reduction':>9} {'effects':>8}")
    worse: list[tuple[str, str, str, dict, dict]] = []
    for label, summary in reports:
        for run_name, per_axis in summary["runs"].items():
            for axis, row in per_axis.items():
                raw = row["raw_rms_um"]
                ours = row["residual_rms_um"]["our model"]
                before = row.get("baseline_rms_um")
                base = f"{before:>8.2f} µm" if before is not None else f"{'—':>11}"
                red = 100.0 * (1.0 - ours / raw) if raw else float("nan")
                line = (f"    {label:<10} {run_name[:26]:<26} {axis:<7} "
                        f"{'yes' if row['in_training'] else 'no':<4} {raw:>6.2f} µm {base} "
                        f"{ours:>9.2f} µm {red:>7.0f} % {effects_on_box(row):>8}")
                if worse_than_baseline(row):
                    worse.append((label, run_name, axis, row, summary))
                    line += f"  <- WORSE than baseline ({len(worse)})"
                demo.say(line)
    for i, (label, run_name, axis, row, summary) in enumerate(worse, 1):
        model = (models or {}).get(label)
        if model is None and summary.get("model"):
            try:
                model = json.loads(Path(summary["model"]).read_text())
            except (OSError, ValueError):
                model = None
        facts = why_worse_than_baseline(axis, row, model, summary, run_name)
        ours, base = row["residual_rms_um"]["our model"], row["baseline_rms_um"]
        head = (f"({i}) {label} {run_name}, {axis}: on this unseen run the box's model is "
                f"WORSE than its baseline ({ours:.2f} vs {base:.2f} µm RMS, "
                f"{100.0 * (ours / base - 1.0):+.0f} %). What model.json and the report say "
                "(facts; which of them caused it is not measured here):")
        demo.say("")
        for ln in textwrap.wrap(head, width=96, break_on_hyphens=False):
            demo.say(f"    {ln}")
        for fact in facts:
            for j, ln in enumerate(textwrap.wrap(fact, width=92, break_on_hyphens=False)):
                demo.say(f"      {'- ' if j == 0 else '  '}{ln}")


def main(argv: Sequence[str] | None = None) -> int:
    del argv
    try:
        checkout.require("the demo (make demo)", str(EXAMPLES / "fl_thermal_steps.csv"),
                         "firmware/Makefile")
    except checkout.CheckoutMissing as exc:
        print(f"demo: {exc}", file=sys.stderr)
        return 2
    demo = Demo()
    demo.say("Thermal-error compensation retrofit: the whole story, every step through the CLI")
    try:
        step_examples(demo)
        sim_model = step_train_sim(demo)
        step_header(demo, BUILD)
        step_firmware(demo, BUILD / "model.h")
        step_hil(demo)
        protocols = step_protocols(demo)
        sim = step_report(demo, BUILD, [*SIM_TRAIN, SIM_TEST], REPORT, protocols, HIL_RESULT)
        fl_parts, fl_model = step_fl(demo)
        step_hil(demo, FL_BUILD / "model.json", fl_parts[1], FL_HIL_RESULT,
                 "HIL: the box replays the hotter unseen cycle (does it know it extrapolates?)")
        fl = step_report(demo, FL_BUILD, fl_parts, FL_REPORT, hil=FL_HIL_RESULT)
    except DemoFailed as exc:
        demo.say(f"\ndemo: step {demo.step_no} ({demo.current}) failed:\n{exc}")
        return 1
    demo.say(f"\nReports: {ROOT / REPORT / 'index.html'} (simulated protocols)")
    demo.say(f"         {ROOT / FL_REPORT / 'index.html'} (real FL_THERMAL data)")
    print_error_table(demo, [("simulated", sim), ("FL_THERMAL", fl)],
                      {"simulated": sim_model, "FL_THERMAL": fl_model})
    demo.say(f"\ndemo finished in {time.monotonic() - demo.started:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))

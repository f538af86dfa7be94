"""`make cnc`: the box's corrections through a real, headless LinuxCNC, judged per sample.

Steps: fit a small 3-axis model on a simulated run and build the native firmware for it (the
HIL's own machinery, hil.replay.prepare); stage the LinuxCNC configuration of cnc/config with
the component, the driver, the decoder, the firmware and the feed in a directory the
unprivileged LinuxCNC user can read (rtapi_app refuses root: as root, a user is created and
LinuxCNC runs as it); run ``linuxcnc`` with cnc/driver.py as its display; then judge what the
driver recorded against the box's own sample lines, decoded by the project's decoder:

- tracking: LinuxCNC's commanded external offset (``axis.L.eoffset``) and the joint's commanded
  position (``joint.N.motor-pos-cmd`` − its start) equal sign × the box's correction within one
  count, on every sample where neither the box nor the component holds;
- an open thermocouple: every offset stays at its value before the fault while the box says
  HOLD, then walks back no faster than the component's limit;
- a stale stream (feeding pauses): ``stale`` and ``holding`` rise, the offsets do not move;
- a corrupted line (one digit flipped by the tap): refused (``bad-lines``), offsets unchanged;
- machine off/on: after machine-on (and the next move) the offset is the box's value again;
- ZERO: the first sample after it is 0 on the box and in LinuxCNC.

``python -m thermal_comp.cnc --probe`` (``make probe``) runs the in-service probing session instead
(issue 42, ``probe_scenario``): no faults; the simulated artifact's surface moves with the run's
drift, the probing subroutine touches it every ``probe_every`` samples and the box corrects its
estimate; ``judge_probes`` checks each reading against the true remaining error, each answer
against the estimator's twin, the chip's refusal, and updated against static.
"""

from __future__ import annotations

import fcntl
import json
import os
import pwd
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from thermal_comp.cnc.judge import Result, clean_reference, fault_rows, judge
from thermal_comp.cnc.probe_judge import PROBE_RESOLUTION_NM, judge_probes, probe_table
from thermal_comp.cnc.programs import (
    default_testplans,
    judge_program,
    short_mcode_testplan,
    short_testplan,
)
from thermal_comp.cnc.scenario import (
    AXES,
    CONFIG_DIR,
    LINUXCNC,
    LOCK,
    MOVED_NM,
    PACKAGE,
    PROBE_AXIS,
    REPLAY_RUN,
    ROOT,
    SESSION_SERVICE,
    SIGN,
    START_MDI,
    SYSTEM_PYTHON,
    TRAIN_RUN,
    USER,
    CncError,
    Scenario,
    campaign_scenario,
    drift_nm,
    probe_scenario,
)
from thermal_comp.contract import checkout

__all__ = ["MOVED_NM", "PROBE_RESOLUTION_NM", "CncError", "Result", "Scenario",
           "campaign_scenario", "clean_reference",
           "default_testplans", "fault_rows", "judge", "judge_probes", "judge_program", "main",
           "prepare_box", "probe_scenario", "probe_table", "run_session", "short_mcode_testplan",
           "short_testplan", "stage"]


def check_linuxcnc() -> None:
    """LinuxCNC (Debian's linuxcnc-uspace) and its Python modules must be there."""
    if not Path(LINUXCNC).is_file():
        raise CncError(f"{LINUXCNC} not found: install the Debian package linuxcnc-uspace "
                       "(scripts/install-system-deps.sh does)")
    probe = subprocess.run([SYSTEM_PYTHON, "-c", "import hal, linuxcnc"], capture_output=True,
                           text=True)
    if probe.returncode != 0:
        raise CncError(f"{SYSTEM_PYTHON} cannot import LinuxCNC's hal/linuxcnc modules: "
                       f"{probe.stderr.strip()[-300:]}")


def run_as() -> str | None:
    """The user LinuxCNC runs as: None (ourselves) unless we are root, then USER (created)."""
    if os.geteuid() != 0:
        return None
    try:
        pwd.getpwnam(USER)
    except KeyError:
        proc = subprocess.run(["useradd", "--create-home", "--shell", "/bin/sh", USER],
                              capture_output=True, text=True)
        if proc.returncode != 0:
            raise CncError(f"useradd {USER} failed (rtapi_app refuses root, LinuxCNC needs an "
                           f"unprivileged user): {proc.stderr.strip()}") from None
    return USER


# --- model, firmware, feed -----------------------------------------------------------------
def prepare_box(build: Path, n_samples: int, service: dict | None = None):
    """A 3-axis model fitted on TRAIN_RUN, the native firmware for it, the replay's feed;
    ``service``: the estimator block every axis gets (MEAS; None: none, MEAS is OFF)."""
    from thermal_comp.hil import replay as hil_replay
    from thermal_comp.hil.example_model import default_terms, fit_example_model, write_model
    from thermal_comp.host.io import load_run, write_run

    sensors = ["T01", "T02", "T03", "T04", "T05", "T06"]
    period = 60.0
    terms = {"dx_um": default_terms(["T03", "T04", "T01"], period, "spindle_rpm"),
             "dy_um": default_terms(["T06", "T07", "T05"], period, None),
             "dz_um": default_terms(["T05", "T01", "T02"], period, "spindle_rpm")}
    fitted = fit_example_model(TRAIN_RUN, terms, aux_names=["spindle_rpm"])
    # the default users get (host train --reference start): the box zeroes at the job's ZERO,
    # boots NO_REF after a power cut (the header's zero_at_powerup follows the reference)
    fitted["reference"] = {"kind": "start", "samples": 1}
    if service is not None:
        for ax in fitted["axes"].values():
            ax["service"] = dict(service)
    model = write_model(fitted, build / "model.json")
    run = load_run(REPLAY_RUN, targets=[a for _, a in AXES], sensors=sensors + ["T07"],
                   aux=["spindle_rpm"])
    n = min(n_samples, run.n_samples)
    cols = {k: v[:n] for k, v in run.columns().items() if k != "time_s"}
    data = build / "replay.csv"
    write_run(data, run.time_s[:n], cols, precision=9)
    setup = hil_replay.prepare(model, data, build / "hil")
    return setup


# --- staging -------------------------------------------------------------------------------
COMPONENT_FILES = ("__init__.py", "thermalcomp.py", "compconfig.py", "compensator.py",
                   "serialport.py", "keptstate.py", "driver.py", "machine.py", "tap.py")


def stage_package(stage_dir: Path) -> Path:
    """The component, the driver, the stdlib-only contract they decode with and the
    configuration, laid out as the package has them (``thermal_comp/cnc``, ``.../contract``), so
    they import each other as from a checkout or a wheel; returns the configuration folder."""
    pkg = stage_dir / "thermal_comp"
    cfg = pkg / "cnc" / "config"
    cfg.mkdir(parents=True)
    shutil.copy2(PACKAGE / "__init__.py", pkg / "__init__.py")
    for f in COMPONENT_FILES:
        shutil.copy2(PACKAGE / "cnc" / f, pkg / "cnc" / f)
    for f in CONFIG_DIR.iterdir():
        if f.is_file():
            shutil.copy2(f, cfg / f.name)
    for sub in ("mcodes", "subroutines"):
        shutil.copytree(CONFIG_DIR / sub, cfg / sub)
    (pkg / "contract").mkdir()
    for f in (PACKAGE / "contract").glob("*.py"):
        shutil.copy2(f, pkg / "contract" / f.name)
    return cfg


def stage(stage_dir: Path, setup, scenario: Scenario) -> Path:
    """Copy the config, component, driver, decoder, firmware and feed; returns the INI."""
    cfg = stage_package(stage_dir)
    pkg = cfg.parent.parent
    shutil.copy2(setup.binary, stage_dir / "box")
    (stage_dir / "feed.txt").write_bytes(b"".join(setup.feed.feed_lines()))
    port = stage_dir / "box-tty"
    conf = (cfg / "thermalcomp.conf").read_text()
    conf = conf.replace("port = /dev/ttyUSB0", f"port = {port}")
    # the replay runs in compressed time: the stale clock counts wall-clock sample periods
    conf = conf.replace("# period_s = 60", f"period_s = {scenario.stale_period_s}")
    conf = conf.replace("stale_periods = 3", f"stale_periods = {scenario.stale_periods:g}")
    # the model the box carries: the component drives only from it (hash, step limits)
    (cfg / "model.json").write_text(json.dumps(setup.model, indent=1))
    conf = conf.replace("# model = /home/cnc/thermal/build/model.json", "model = model.json")
    (cfg / "thermalcomp-session.conf").write_text(conf)
    ini = (cfg / "thermal_sim.ini").read_text()
    ini = ini.replace("DISPLAY = axis", f"DISPLAY = {pkg / 'cnc' / 'driver.py'}")
    ini = ini.replace("CONFIG = thermalcomp.conf",
                      "CONFIG = thermalcomp-session.conf\nDRIVER_PLAN = plan.json")
    (cfg / "thermal_sim_session.ini").write_text(ini)
    programs = []
    for i, tp in enumerate(scenario.testplans):
        if tp.dialect != "linuxcnc" or tp.trigger.strip().upper() not in ("M100", "M64 P0"):
            raise CncError("the session runs test plans of --dialect linuxcnc triggered by "
                           "'M64 P0' (it watches motion.digital-out-00) or M100 (the "
                           "configuration's cnc/config/mcodes/M100 logs each call)")
        path = cfg / f"thermal_test_{i}.ngc"
        tp.write(path)
        prog = {"path": str(path), "timeout_s": tp.duration_s * 1.5 + 10.0}
        if tp.digital_output is not None:
            prog["trigger_pin"] = f"motion.digital-out-{tp.digital_output:02d}"
        else:
            prog["trigger_log"] = str(cfg / "thermal_triggers.log")
        programs.append(prog)
    plan = {"firmware": str(stage_dir / "box"), "feed": str(stage_dir / "feed.txt"),
            "port_link": str(port), "results": str(stage_dir / "results.json"),
            "axes": [{"letter": letter, "box_axis": a} for letter, a in AXES],
            "start_mdi": START_MDI, "events": scenario.events(), "timeout_s": 10.0,
            "retain": str(stage_dir / "retain.bin"), "zero_at_start": scenario.zero_at_start,
            "programs": programs}
    if scenario.probe_every:
        plan["probe"] = probe_plan(setup, scenario)
    (cfg / "plan.json").write_text(json.dumps(plan, indent=1))
    for p in (stage_dir, *stage_dir.rglob("*")):
        p.chmod(0o755 if p.is_dir() or os.access(p, os.X_OK) else 0o644)
    return cfg / "thermal_sim_session.ini"


def probe_plan(setup, scenario: Scenario) -> dict:
    """The driver's probing plan: where the artifact's surface is at each sample (its drift
    along Z in machine coordinates: with sign -1 the box's displacement is the machine's),
    when to probe and where the chip is."""
    chip = scenario.chip_sample()
    return {"axis": PROBE_AXIS, "sub": "probe_ref", "return_mdi": START_MDI,
            "at": scenario.probe_samples(),
            "drift_mm": [-SIGN * v / 1e6 for v in drift_nm(setup)],
            "chips": {} if chip is None else {str(chip): scenario.chip_um / 1000.0}}


def launch(ini: Path, stage_dir: Path, user: str | None,
           timeout_s: float) -> tuple[int, str, float, float]:
    """Run linuxcnc on ``ini`` (as ``user``), headless; returns (exit code, its output, seconds
    waited for another session's LinuxCNC, seconds LinuxCNC ran)."""
    env = {"PATH": "/usr/sbin:/usr/bin:/sbin:/bin", "HOME": str(stage_dir), "RUNTESTS": "1",
           "LANG": "C.UTF-8"}
    cmd = ["timeout", f"{timeout_s:g}", LINUXCNC, str(ini)]
    if user is not None:
        pw = pwd.getpwnam(user)
        os.chown(stage_dir, pw.pw_uid, pw.pw_gid)
        for p in stage_dir.rglob("*"):
            os.chown(p, pw.pw_uid, pw.pw_gid, follow_symlinks=False)
        cmd = ["runuser", "-u", user, "--", *cmd]
    with LOCK.open("a") as lock:  # one LinuxCNC per machine (shared memory, lock file)
        if os.geteuid() == 0:
            os.chmod(LOCK, 0o666)  # a later non-root run may take it too
        t0 = time.monotonic()
        fcntl.flock(lock, fcntl.LOCK_EX)
        t1 = time.monotonic()
        proc = subprocess.run(cmd, cwd=ini.parent, env=env, capture_output=True, text=True)
    return proc.returncode, (proc.stdout + proc.stderr), t1 - t0, time.monotonic() - t1


# --- the summary printed ----------------------------------------------------------------
def table(summary: dict, elapsed_s: float) -> str:
    s = summary
    wait = s.get("lock_wait_s", 0.0)
    lines = [f"LinuxCNC external offsets driven by the box: {s['samples']} samples "
             f"({s['tracked_samples']} tracked), {elapsed_s - wait:.1f} s"
             + (f" (+{wait:.0f} s waiting for another LinuxCNC)" if wait >= 1 else ""),
             "",
             f"{'largest |LinuxCNC offset - box correction|':46s} {s['max_abs_diff_nm']:9.3f} nm"
             f"  {s['max_abs_diff_counts']:.3f} counts",
             f"{'largest |joint pos-cmd move - box correction|':46s} "
             f"{s['max_abs_joint_diff_nm']:9.3f} nm",
             f"{'bad lines refused / lines lost':46s} {s['bad_lines']:9d} / {s['lost_lines']}",
             "",
             f"{'event injected':24s}{'samples':>8s}  {'box says':12s}{'handled':>8s}"
             f"{'off by nm':>11s}",
             "-" * 65]
    for h in s["holds"]:  # off by: how far an offset moved while held, or missed after resync
        lines.append(f"{h['fault']:24s}{h['samples']:8d}  {h['box_status']:12s}"
                     f"{'yes' if h['held'] else 'NO':>8s}{h['moved_nm']:11.3f}")
    if s.get("events"):
        letters = [letter for letter, _ in AXES]
        lines += ["", "the rule: no single event moves the tool further from the clean run than "
                  "one step limit (+1 count)",
                  f"{'controller event':28s}{'at':>5s}  "
                  + "".join(f"{a + ' um (bound)':>17s}" for a in letters) + "  result",
                  "-" * 86]
        for e in s["events"]:
            lines.append(f"{e['scenario']:28s}{e['at']:5d}  "
                         + "".join(f"{e['increase_um'][a]:8.3f} ({e['bound_um'][a]:6.3f})"
                                   for a in letters)
                         + f"  {'PASS' if e['ok'] else 'FAIL'}")
            lines.append(f"{'':35s}{e['detail']}")
            lines.append(f"{'':35s}flags: {', '.join(e['flags']) or '-'}")
        t = s.get("box_vs_twin", {})
        same = t.get("compared", 0) - t.get("mismatches", 0)
        lines.append(f"clean run: the twin's lines (box = twin on {same}/{t.get('compared', 0)} "
                     "samples before the first power cut) through the component's rules")
    if s.get("probe"):
        lines += probe_table(s["probe"])
    z = s["zero"]
    lines.append("")
    if s.get("probe"):
        pass  # the probing session's only ZERO is the job's, before the reference touch
    elif z.get("done"):
        lines.append(f"ZERO at sample {z['sample']}: box replied {z['reply']!r}, box output "
                     f"{'0' if z['box_zero'] else 'not 0'}, LinuxCNC offset "
                     f"{z['offset_nm']:.3f} nm -> {'PASS' if z['ok'] else 'FAIL'}")
    else:
        lines.append("ZERO: not run")
    for prog in s.get("programs", []):
        lines.append(f"test program (host testplan --dialect linuxcnc, {prog['trigger']}): "
                     f"{prog.get('measurements_found', 0)}/{prog['measurements_expected']} "
                     f"triggers, largest timing error {prog.get('max_trigger_error_s', 0):.3f} "
                     f"s, {prog.get('stopped_and_oriented', 0)} stopped+oriented, "
                     f"{prog.get('speeds_checked', 0) - len(prog.get('speeds_wrong', []))}/"
                     f"{prog.get('speeds_checked', 0)} speeds as scheduled")
    lines += ["", "RESULT: " + ("PASS" if s["ok"] else "FAIL")]
    lines += [f"  - {p}" for p in s["problems"]]
    return "\n".join(lines)


def run_session(build: Path, scenario: Scenario | None = None, timeout_s: float = 110.0,
                keep: bool = False) -> Result:
    """The whole session: prepare, stage, run LinuxCNC, judge; writes build/summary.json."""
    scenario = scenario or Scenario()
    check_linuxcnc()
    build.mkdir(parents=True, exist_ok=True)
    setup = prepare_box(build, scenario.n_samples,
                        SESSION_SERVICE if scenario.probe_every else None)
    scenario.n_samples = setup.feed.n_samples
    user = run_as()
    stage_dir = Path(tempfile.mkdtemp(prefix="thermal-cnc-"))
    t0 = time.monotonic()
    try:
        ini = stage(stage_dir, setup, scenario)
        for f in ini.parent.glob("thermal_test_*.ngc"):
            shutil.copy2(f, build / f.name)
        code, output, waited_s, ran_s = launch(ini, stage_dir, user, timeout_s)
        (build / "linuxcnc.log").write_text(output)
        results = stage_dir / "results.json"
        if not results.is_file():
            raise CncError(f"LinuxCNC exited with {code} and the driver wrote no results "
                           f"(see {build / 'linuxcnc.log'}):\n{output[-2000:]}")
        raw = json.loads(results.read_text())
        shutil.copy2(results, build / "results.json")
    finally:
        if not keep:
            shutil.rmtree(stage_dir, ignore_errors=True)
    clean = clean_reference(setup, scenario)
    probing = bool(scenario.probe_every)
    # with readings the box's lines carry the estimate: judge_probes compares them with the
    # twin given the same readings instead of the clean run
    result = judge(raw, step_nm=1000.0 * setup.spec.sample_period_s,
                   clean=None if probing else clean, events=scenario.controller_events())
    if probing:
        pr = judge_probes(raw, setup, scenario, clean)
        pr["every"] = scenario.probe_every
        result.summary["probe"] = pr
        result.problems += pr["problems"]
        result.summary["problems"] = result.problems
        result.summary["ok"] = not result.problems
    if scenario.testplans:
        recorded = raw.get("programs", [])
        progs = [judge_program(tp, recorded[i] if i < len(recorded) else None)
                 for i, tp in enumerate(scenario.testplans)]
        result.summary["programs"] = progs
        for prog in progs:
            result.problems += prog["problems"]
        result.summary["problems"] = result.problems
        result.summary["ok"] = not result.problems
    result.summary["elapsed_s"] = time.monotonic() - t0
    result.summary["lock_wait_s"] = waited_s  # another session's LinuxCNC was running
    result.summary["linuxcnc_s"] = ran_s
    result.summary["driver_s"] = raw.get("elapsed_s")
    result.summary["linuxcnc_exit"] = code
    (build / "summary.json").write_text(json.dumps(result.summary, indent=2))
    return result


def main(argv: list[str] | None = None) -> int:
    import argparse

    ap = argparse.ArgumentParser(prog="python -m thermal_comp.cnc",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("--build-dir", default=str(ROOT / "build" / "cnc"))
    ap.add_argument("--samples", type=int, default=961)
    ap.add_argument("--keep", action="store_true", help="keep the staged LinuxCNC directory")
    ap.add_argument("--no-program", action="store_true",
                    help="skip the test programs (host testplan --dialect linuxcnc)")
    ap.add_argument("--probe", action="store_true",
                    help="the in-service probing session instead (make probe): a probe every "
                         "--probe-every samples, the residual at each, static against updated")
    ap.add_argument("--probe-every", type=int, default=60, help="samples between probes")
    args = ap.parse_args(argv)
    try:
        checkout.require("make cnc (a run through the native box into LinuxCNC)",
                         str(REPLAY_RUN.relative_to(ROOT)), "firmware/Makefile")
    except checkout.CheckoutMissing as exc:
        print(f"cnc: {exc}", file=sys.stderr)
        return 2
    try:
        if args.probe:
            scenario = probe_scenario(args.samples, args.probe_every)
            if args.build_dir == str(ROOT / "build" / "cnc"):
                args.build_dir = str(ROOT / "build" / "cnc-probe")
        else:
            scenario = Scenario(n_samples=args.samples,
                                testplans=() if args.no_program else default_testplans())
        result = run_session(Path(args.build_dir), scenario, keep=args.keep)
    except CncError as exc:
        print(f"cnc: {exc}")
        return 2
    print(table(result.summary, result.summary["elapsed_s"]))
    print(f"\nwrote {Path(args.build_dir) / 'summary.json'}")
    return 0 if result.summary["ok"] else 1

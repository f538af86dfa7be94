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

``python -m cnc --probe`` (``make probe``) runs the in-service probing session instead (issue
42, ``probe_scenario``): no faults; the simulated artifact's surface moves with the run's
drift, the probing subroutine touches it every ``probe_every`` samples and the box corrects
its estimate; ``judge_probes`` checks each reading against the true remaining error, each
answer against the estimator's twin, the chip's refusal, and updated against static.
"""

from __future__ import annotations

import fcntl
import json
import math
import os
import pwd
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from host.sim import ThermalTestPlan, build_program

ROOT = Path(__file__).resolve().parents[1]
CONFIG_DIR = ROOT / "cnc" / "config"
USER = os.environ.get("THERMAL_CNC_USER", "thermal-cnc")
LOCK = Path(tempfile.gettempdir()) / "thermal-cnc-linuxcnc.lock"
LINUXCNC = "/usr/bin/linuxcnc"
SYSTEM_PYTHON = "/usr/bin/python3"
AXES = [("x", "dx_um"), ("y", "dy_um"), ("z", "dz_um")]  # as cnc/config/thermalcomp.conf
SIGN = -1
START_MDI = "G90 G0 X0 Y0 Z-50"
HOLD_BITS = (1 << 0) | (1 << 1) | (1 << 9) | (1 << 12)  # MODEL_BAD, HOLD, NO_DATA, IMPLAUSIBLE
MOVED_NM = 0.01  # "did not move": LinuxCNC's planner settles within hundredths of a nm
TRAIN_RUN = ROOT / "examples" / "sim_step.csv"
REPLAY_RUN = ROOT / "examples" / "sim_random.csv"


class CncError(RuntimeError):
    """LinuxCNC is missing, could not be run, or the session did not complete."""


@dataclass
class Scenario:
    """What the session injects, by sample index of the replayed run.

    Besides the faults the component holds on (open thermocouple, stale stream, corrupted
    line, machine off/on, enable off/on, ZERO), the controller events of issue 41's rule,
    each judged against the clean run (``fault_rows``): a forged CRC-valid line
    (``forged_at``: after that sample, every correction +``forged_delta_um``), noise on the
    wire (``garbage_at``: random bytes and a 16 KiB run without a newline, before that
    sample), a dropped and restored link (``reconnect_at`` for ``reconnect_samples``
    samples), a watchdog restart (``wdt_at``: the box killed and started with
    ``--wdt-reset`` on its retained memory) and power cuts (``power_cuts``: (sample, samples
    until the operator's ZERO) each; the box boots cold, NO_REF)."""

    n_samples: int = 961
    open_at: int | None = 200
    open_stop: int = 260
    open_channel: int = 0
    stale_at: int | None = 350
    bad_at: int | None = 420
    off_at: int | None = 500
    off_samples: int = 5
    disable_at: int | None = 600
    disable_samples: int = 5
    zero_at: int | None = 700
    forged_at: int | None = 120
    forged_delta_um: float = 60.0
    garbage_at: int | None = 300
    reconnect_at: int | None = 380
    reconnect_samples: int = 2
    wdt_at: int | None = 450
    power_cuts: tuple[tuple[int, int], ...] = ((800, 1), (880, 3))
    zero_at_start: bool = True  # a start-referenced box holds (NO_REF) until the job's ZERO
    stale_period_s: float = 0.1  # the component's stale clock in the time-compressed replay
    stale_periods: float = 3.0
    testplans: tuple[ThermalTestPlan, ...] = ()  # run after the replay, in AUTO (linuxcnc)
    # probing in service (issue 42): the probing subroutine every probe_every samples (from
    # sample probe_every on), a chip on the artifact (+chip_um) at probe number chip_probe
    probe_every: int | None = None
    chip_probe: int | None = None
    chip_um: float = 50.0

    def probe_samples(self) -> list[int]:
        if not self.probe_every:
            return []
        # not after the last sample: its answer would act on no sample
        return list(range(self.probe_every, self.n_samples - 1, self.probe_every))

    def chip_sample(self) -> int | None:
        at = self.probe_samples()
        return at[self.chip_probe] if self.chip_probe is not None and \
            self.chip_probe < len(at) else None

    def events(self) -> dict:
        ev: dict = {}
        if self.open_at is not None:
            ev["open"] = {"at": self.open_at, "stop": self.open_stop,
                          "channel": self.open_channel}
        if self.stale_at is not None:
            ev["stale"] = {"at": self.stale_at,
                           "pause_s": 3 * self.stale_period_s * self.stale_periods}
        if self.bad_at is not None:
            ev["bad_line"] = {"at": self.bad_at}
        if self.off_at is not None:
            ev["machine_off"] = {"at": self.off_at, "samples": self.off_samples}
        if self.disable_at is not None:
            ev["disable"] = {"at": self.disable_at, "samples": self.disable_samples}
        if self.zero_at is not None:
            ev["zero"] = {"at": self.zero_at}
        if self.forged_at is not None:
            ev["forged"] = {"at": self.forged_at,
                            "delta_nm": round(self.forged_delta_um * 1000.0)}
        if self.garbage_at is not None:
            ev["garbage"] = {"at": self.garbage_at, "seed": 41}
        if self.reconnect_at is not None:
            ev["reconnect"] = {"at": self.reconnect_at, "samples": self.reconnect_samples}
        if self.wdt_at is not None:
            ev["wdt_restart"] = {"at": self.wdt_at}
        out = {k: v for k, v in ev.items() if _inside(v, self.n_samples)}
        cuts = [{"at": at, "zero_after": after} for at, after in self.power_cuts
                if at + after < self.n_samples]
        if cuts:
            out["power_cut"] = cuts
        return out

    def controller_events(self) -> list[tuple[str, int]]:
        """(scenario name, sample) of each event judged by the rule, in order."""
        ev = self.events()
        named = [("forged line", "forged"), ("garbage on the wire", "garbage"),
                 ("stale stream", "stale"), ("reconnect", "reconnect"),
                 ("corrupted line", "bad_line"), ("watchdog restart", "wdt_restart")]
        out = [(name, int(ev[key]["at"])) for name, key in named if key in ev]
        out += [(f"power cut (ZERO after {c['zero_after']})", int(c["at"]))
                for c in ev.get("power_cut", [])]
        return sorted(out, key=lambda e: e[1])


def campaign_scenario() -> Scenario:
    """Every controller event of the fault campaign (hil/faults.py: ``make faults``) on the
    whole replay, without the test programs: run it with ``run_session`` and turn the result
    into rows with ``fault_rows``."""
    return Scenario(testplans=())


def probe_scenario(n_samples: int = 961, every: int = 60, chip_probe: int | None = 8
                   ) -> Scenario:
    """In-service probing (``make probe``): the job's ZERO and reference touch, then the
    probing subroutine every ``every`` samples (60: hourly in the replayed run), a chip on
    the artifact at probe number ``chip_probe``; no faults, no test programs."""
    return Scenario(n_samples=n_samples, open_at=None, stale_at=None, bad_at=None,
                    off_at=None, disable_at=None, zero_at=None, forged_at=None,
                    garbage_at=None, reconnect_at=None, wdt_at=None, power_cuts=(),
                    probe_every=every, chip_probe=chip_probe)


# The session's model carries this estimator block when it probes (docs/service.md): train's
# fields, set here rather than derived (the example model is not fitted by host train). q:
# the wander of this model's residual on the replayed day is about 4 um^2 per hour.
SESSION_SERVICE = {"q_um2_per_h": 4.0, "probe_noise_um": 0.5, "gate_sigma": 4.0,
                   "gate_floor_um": 3.0, "p_max_um2": 100.0,
                   "why": "make probe: q 4 um^2/h (this example model's residual on the "
                          "replayed day wanders by about 2 um per hour); p_max 100 um^2 keeps "
                          "the gate below 41 um, so a +50 um chip is refused"}


def _inside(event: dict, n: int) -> bool:
    return int(event["at"]) < n


@dataclass
class Result:
    summary: dict
    raw: dict
    problems: list[str] = field(default_factory=list)


# --- environment ---------------------------------------------------------------------------
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
    from hil import replay as hil_replay
    from hil.example_model import default_terms, fit_example_model, write_model
    from host.io import load_run, write_run

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
def stage(stage_dir: Path, setup, scenario: Scenario) -> Path:
    """Copy the config, component, driver, decoder, firmware and feed; returns the INI."""
    (stage_dir / "cnc" / "config").mkdir(parents=True)
    for f in ("thermalcomp.py", "compconfig.py", "compensator.py", "serialport.py",
              "keptstate.py", "driver.py"):
        shutil.copy2(ROOT / "cnc" / f, stage_dir / "cnc" / f)
    for f in CONFIG_DIR.iterdir():
        if f.is_file():
            shutil.copy2(f, stage_dir / "cnc" / "config" / f.name)
    for sub in ("mcodes", "subroutines"):
        shutil.copytree(CONFIG_DIR / sub, stage_dir / "cnc" / "config" / sub)
    # the stdlib-only contract package the component imports its decoder from
    (stage_dir / "contract").mkdir()
    for f in (ROOT / "contract").glob("*.py"):
        shutil.copy2(f, stage_dir / "contract" / f.name)
    cfg = stage_dir / "cnc" / "config"
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
    ini = ini.replace("DISPLAY = axis", f"DISPLAY = {stage_dir / 'cnc' / 'driver.py'}")
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


PROBE_AXIS = "z"  # the axis the probe measures ([probe] axis in thermalcomp.conf)


def drift_nm(setup, letter: str = PROBE_AXIS) -> list[float]:
    """The machine's thermal displacement of the tool along the axis at each sample (nm, the
    box's sign: tool relative to work), since the run's first sample: the replayed run's
    measured displacement, which the simulated artifact's surface follows."""
    box_axis = dict(AXES)[letter]
    d = [float(v) for v in setup.feed.measured[box_axis]]
    return [(v - d[0]) * 1000.0 for v in d]


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


# --- judging -------------------------------------------------------------------------------
@dataclass
class _Records:
    """The session's sample records, by sample and by phase, with the box's correction and
    LinuxCNC's offset of each in nm."""

    records: list[dict]
    base: dict  # each axis's joint position before the session (mm)
    nm_per_count: float
    letters: list[str] = field(default_factory=lambda: [letter for letter, _ in AXES])
    idx: dict[int, dict] = field(init=False)
    by_phase: dict[str, list[dict]] = field(init=False)

    def __post_init__(self) -> None:
        self.idx = {r["sample"]: r for r in self.records}
        self.by_phase = {}
        for r in self.records:
            self.by_phase.setdefault(r["phase"], []).append(r)

    def want_nm(self, rec: dict, i: int) -> float:
        return SIGN * rec["box"]["corr_nm"][i] if rec["box"]["corr_nm"] else float("nan")

    def offset_diff_nm(self, rec: dict) -> float:
        """|LinuxCNC's external offset - the box's correction|, the worst axis."""
        return max(abs(rec["eoffset_mm"][a] * 1e6 - self.want_nm(rec, i))
                   for i, a in enumerate(self.letters))

    def joint_diff_nm(self, rec: dict) -> float:
        """|the joint's commanded move since the start - the box's correction|, worst axis."""
        return max(abs((rec["pos_cmd_mm"][a] - self.base[a]) * 1e6 - self.want_nm(rec, i))
                   for i, a in enumerate(self.letters))

    def moved_nm(self, rs: list[dict], ref: dict) -> float:
        return max((abs(r["eoffset_mm"][a] - ref["eoffset_mm"][a]) * 1e6
                    for r in rs for a in self.letters), default=0.0)


def _tracking(rec: _Records, problems: list[str],
              cuts: tuple[int, ...] = ()) -> tuple[int, float, float]:
    """On every healthy sample, the offset and the joint follow the box within a count:
    (samples tracked, worst offset difference, worst joint difference) in nm.

    After a power cut the component carries the offsets it held as a base and adds the box's
    change since the operator's ZERO: from then on the offset is base - correction, the base
    taken at the first healthy sample after the cut (the power cut's row judges the base
    itself against the clean run)."""
    max_off = max_joint = 0.0
    tracked = 0
    base = {a: 0.0 for a in rec.letters}
    segment = 0
    for r in rec.records:
        while segment < len(cuts) and r["sample"] >= cuts[segment]:
            segment, base = segment + 1, {}
        healthy = (not r["box"]["status"] & HOLD_BITS and not r["holding"]
                   and not r["walking"] and not r["box"]["corrupted"]
                   and r["box"].get("delivered", True)
                   and r["phase"] not in ("machine_off", "disabled", "garbage"))
        if not healthy:
            continue
        if not base:
            base = {a: r["eoffset_mm"][a] * 1e6 - rec.want_nm(r, i)
                    for i, a in enumerate(rec.letters)}
        tracked += 1
        max_off = max(max_off, max(abs(r["eoffset_mm"][a] * 1e6 - base[a] - rec.want_nm(r, i))
                                   for i, a in enumerate(rec.letters)))
        max_joint = max(max_joint, max(
            abs((r["pos_cmd_mm"][a] - rec.base[a]) * 1e6 - base[a] - rec.want_nm(r, i))
            for i, a in enumerate(rec.letters)))
    if tracked == 0:
        problems.append("no sample was tracked (every one held or walking)")
    if max_off > rec.nm_per_count:
        problems.append(f"LinuxCNC's external offset differs from the box's correction by "
                        f"{max_off:.3f} nm (> 1 count = {rec.nm_per_count:g} nm)")
    if max_joint > rec.nm_per_count:
        problems.append(f"the joints' commanded positions moved by the correction ± "
                        f"{max_joint:.3f} nm (> 1 count)")
    return tracked, max_off, max_joint


def _open_thermocouple(rec: _Records, step_nm: float, problems: list[str]) -> list[dict]:
    """Held on every sample of the fault, then walked back no faster than the step limit."""
    opened = rec.by_phase.get("open", [])
    if not opened:
        return []
    letters = rec.letters
    before = rec.idx.get(opened[0]["sample"] - 1)
    boxheld = sum(1 for r in opened if r["box"]["status"] & (1 << 1))
    moved = rec.moved_nm(opened, before) if before else float("nan")
    ok = before is not None and moved <= MOVED_NM and all(r["holding"] for r in opened) \
        and boxheld == len(opened)
    after = [rec.idx[k] for k in range(opened[-1]["sample"], opened[-1]["sample"] + 20)
             if k in rec.idx]
    steps = [abs(b["eoffset_mm"][a] - p["eoffset_mm"][a]) * 1e6
             for p, b in zip(after[:-1], after[1:], strict=True) for a in letters]
    walk_ok = max(steps, default=0.0) <= step_nm + rec.nm_per_count
    if not ok:
        problems.append(f"open thermocouple: offsets moved {moved:g} nm or were not held "
                        f"on every sample ({boxheld}/{len(opened)} HOLD from the box)")
    if not walk_ok:
        problems.append(f"after the open thermocouple an offset stepped "
                        f"{max(steps):g} nm in one sample (limit {step_nm:g})")
    return [{"fault": "open thermocouple", "samples": len(opened),
             "box_status": "OPEN|HOLD" if boxheld else "-", "held": ok,
             "moved_nm": moved, "walk_back_ok": walk_ok}]


def _stale_pauses(raw: dict, rec: _Records, problems: list[str]) -> list[dict]:
    """A silent box: the driver flags stale and holds, and nothing moves."""
    holds = []
    for p in [r for r in raw.get("records", []) if r.get("phase") == "stale_pause"]:
        b, d = p["before"], p["during"]
        moved = max(abs(d["eoffset_mm"][a] - b["eoffset_mm"][a]) * 1e6 for a in rec.letters)
        ok = bool(d["stale"]) and bool(d["holding"]) and moved <= MOVED_NM and not b["stale"]
        holds.append({"fault": "stale stream", "samples": 0, "box_status": "(silent)",
                      "held": ok, "moved_nm": moved, "age_s": d["age-s"]})
        if not ok:
            problems.append(f"stale stream: stale={d['stale']} holding={d['holding']} "
                            f"moved {moved:g} nm (age {d['age-s']:.3f} s)")
    return holds


def _corrupted_lines(rec: _Records, problems: list[str]) -> list[dict]:
    """A line with a bad CRC is refused (counted) and moves nothing."""
    holds = []
    for r in rec.by_phase.get("bad_line", []):
        prev = rec.idx.get(r["sample"] - 1)
        moved = rec.moved_nm([r], prev) if prev else float("nan")
        refused = prev is not None and r["bad-lines"] == prev["bad-lines"] + 1
        ok = r["box"]["corrupted"] and refused and moved <= MOVED_NM
        holds.append({"fault": "corrupted line (CRC)", "samples": 1, "box_status": "-",
                      "held": ok, "moved_nm": moved})
        if not ok:
            problems.append(f"corrupted line at sample {r['sample']}: refused={refused}, "
                            f"offsets moved {moved:g} nm")
    return holds


def _machine_off_on(rec: _Records, problems: list[str]) -> tuple[list[dict], dict]:
    """After machine off/on the offset and the joint are back on the box's correction."""
    holds: list[dict] = []
    resync: dict = {}
    for r in rec.by_phase.get("machine_on", []):
        d_off, d_joint = rec.offset_diff_nm(r), rec.joint_diff_nm(r)
        resync = {"sample": r["sample"], "offset_diff_nm": d_off, "joint_diff_nm": d_joint,
                  "ok": d_off <= rec.nm_per_count and d_joint <= rec.nm_per_count}
        holds.append({"fault": "machine off/on",
                      "samples": len(rec.by_phase.get("machine_off", [])), "box_status": "-",
                      "held": resync["ok"], "moved_nm": d_off})
        if not resync["ok"]:
            problems.append(f"after machine off/on the offset is {d_off:g} nm and the joint "
                            f"{d_joint:g} nm away from the box's correction")
    return holds, resync


def _enable_off_on(rec: _Records, problems: list[str]) -> list[dict]:
    """Disabled, the offset is 0; enabled again, it is the box's correction."""
    disabled = rec.by_phase.get("disabled", [])
    if not disabled:
        return []
    off = max(abs(r["eoffset_mm"][a]) * 1e6 for r in disabled for a in rec.letters)
    d_back = max((rec.offset_diff_nm(r) for r in rec.by_phase.get("enabled", [])),
                 default=float("inf"))
    ok = off <= rec.nm_per_count and d_back <= rec.nm_per_count
    if not ok:
        problems.append(f"enable off/on: offset {off:g} nm while disabled (want 0), "
                        f"{d_back:g} nm from the box's value after enable")
    return [{"fault": "enable off/on", "samples": len(disabled),
             "box_status": "-", "held": ok, "moved_nm": d_back}]


def _zero(raw: dict, rec: _Records, problems: list[str]) -> dict:
    """After ZERO the box sends 0 and LinuxCNC's offset and joint are back at their start."""
    zero: dict = {"done": False, "ok": False}
    sent = [r for r in raw.get("records", []) if r.get("phase") == "zero_sent"]
    for r in rec.by_phase.get("zero", []):
        box_zero = all(c == 0 for c in r["box"]["corr_nm"])
        off = max(abs(r["eoffset_mm"][a]) * 1e6 for a in rec.letters)
        joint = max(abs(r["pos_cmd_mm"][a] - rec.base[a]) * 1e6 for a in rec.letters)
        zero = {"done": True, "sample": r["sample"], "reply": sent[0]["reply"] if sent else "",
                "box_zero": box_zero, "offset_nm": off, "joint_nm": joint,
                "referenced": bool(r["box"]["status"] & (1 << 11)),
                "ok": box_zero and off <= rec.nm_per_count and joint <= rec.nm_per_count}
        if not zero["ok"]:
            problems.append(f"ZERO: box output {r['box']['corr_nm']}, LinuxCNC offset "
                            f"{off:g} nm, joint {joint:g} nm from its start")
    return zero


# --- the rule: no single event worse than the clean run by more than one step limit --------
def clean_reference(setup, scenario: Scenario) -> dict:
    """The offsets a clean session would command, computed without the component or LinuxCNC.

    The clean box's lines come from the host's twin (hil.expect: bit-exact with the firmware,
    as the HIL checks) for the same feed with only the non-controller events (the open
    thermocouple, the job's ZERO and the ZERO at ``zero_at``); the component's documented
    rules (docs/linuxcnc.md) turn them into offsets: hold every axis on a hold bit, else move
    towards sign x correction by at most min(step limit, slew) per line, within
    ``max_abs_um``, and take the first line after an acknowledged ZERO at once."""
    import numpy as np

    from cnc import thermalcomp
    from contract.fixed_point import CODE_MAX, CODE_MIN
    from hil.expect import expect_session, sr_timeline

    feed, model = setup.feed, setup.model
    n = feed.n_samples
    codes = np.clip(np.asarray(feed.codes, dtype=np.int64), CODE_MIN, CODE_MAX)
    faults = []
    if scenario.open_at is not None and scenario.open_at < n:
        faults = [(scenario.open_at, scenario.open_channel, 1),
                  (min(scenario.open_stop, n), scenario.open_channel, 0)]
    sr = sr_timeline(n, codes.shape[1], [f for f in faults if f[0] < n])
    zeros = ([0] if scenario.zero_at_start else []) + (
        [scenario.zero_at] if scenario.zero_at is not None and scenario.zero_at < n else [])
    exp = expect_session(setup.twin, codes, feed.aux, sr, setup.output, zero_before=zeros,
                         zero_at_powerup=setup.build.zero_at_powerup)
    cfg = thermalcomp.load_config(CONFIG_DIR / "thermalcomp.conf")
    names = list(model["axes"])
    period_s = float(model["sample_period_s"])
    slew_nm = cfg.slew_nm_per_s * round(period_s * 1000.0) / 1000.0
    max_abs_nm = cfg.max_abs_um * 1000.0
    steps = {a.letter: float(thermalcomp.axis_step_nm(CONFIG_DIR, f"axis.{a.letter}",
                                                        a.box_axis, model, None, True))
             for a in cfg.axes}
    offset: dict[str, list[float]] = {a.letter: [] for a in cfg.axes}
    want = {a.letter: 0 for a in cfg.axes}
    datum = False
    for k in range(n):
        datum = datum or k in zeros
        if exp.status[k] & thermalcomp.HOLD_BITS:
            pass  # every axis keeps its offset (a datum change waits for the next line)
        else:
            for a in cfg.axes:
                bound = math.floor(max_abs_nm / a.nm_per_count + 1e-9)
                corr = int(exp.out_nm[k, names.index(a.box_axis)])
                target = max(-bound, min(bound, round(a.sign * corr / a.nm_per_count)))
                if datum:
                    want[a.letter] = target
                else:
                    step = max(1, math.floor(min(steps[a.letter], slew_nm) / a.nm_per_count
                                             + 1e-9))
                    w = want[a.letter]
                    want[a.letter] = max(-bound, min(bound, w + max(-step, min(step,
                                                                                target - w))))
            datum = False
        for a in cfg.axes:
            offset[a.letter].append(want[a.letter] * a.nm_per_count)
    return {"corr_nm": [[int(v) for v in row] for row in exp.out_nm],
            "status": [int(v) for v in exp.status], "offset_nm": offset, "step_nm": steps,
            "nm_per_count": {a.letter: a.nm_per_count for a in cfg.axes},
            "box_axes": {a.letter: names.index(a.box_axis) for a in cfg.axes}}


FLAG_SAMPLES = 10  # the flags reported for an event: those seen in its first samples
_FLAG_PINS = ("holding", "fault", "stale", "awaiting-zero", "walking", "model-mismatch")
_COUNTERS = ("bad-lines", "lost-lines", "restarts", "zero-acks")


def _flags(window: list[dict], before: dict | None, clean_status: list[int]) -> list[str]:
    """The component's flags seen over a window, its counters' increments, and the box's
    status bits that the clean run does not have there."""
    flags = [pin for pin in _FLAG_PINS if any(r.get(pin) for r in window)]
    if any(not r.get("connected", True) for r in window):
        flags.append("disconnected")
    for c in _COUNTERS:
        most = max((r[c] for r in window if c in r), default=None)
        if most is not None and before is not None and most > before[c]:
            flags.append(f"{c} +{most - before[c]}")
    extra = 0
    for r in window:
        if "box" in r and r["sample"] < len(clean_status):
            extra |= r["box"]["status"] & ~clean_status[r["sample"]]
    from contract.protocol import status_names

    flags += [f"box {name}" for name in status_names(extra)]
    return flags


def _judge_events(raw: dict, rec: _Records, clean: dict, events: list[tuple[str, int]],
                  problems: list[str]) -> list[dict]:
    """Per controller event: over its samples (from the event to the next one, or the end),
    per axis the largest |LinuxCNC offset - the clean run's offset|, against one step limit
    (+ 1 count). Samples with the machine off or compensation disabled are not compared."""
    n = len(clean["status"])
    extras = [r for r in raw.get("records", []) if r.get("phase") in ("forged", "stale_pause")]
    rows = []
    for i, (name, at) in enumerate(events):
        end = events[i + 1][1] if i + 1 < len(events) else n
        window = [r for r in rec.records if at <= r["sample"] < end
                  and r["phase"] not in ("machine_off", "disabled")]
        # (snapshot, the sample whose clean offset the tool should have then)
        compared = [(r, r["sample"]) for r in window]
        for x in extras:
            if at <= x["sample"] < end:
                if x["phase"] == "forged":
                    compared.append((x, x["sample"]))
                elif x["sample"] > 0:
                    compared.append((x["during"], x["sample"] - 1))
        inc, bound, detail = {}, {}, []
        ok = bool(window)
        for a in rec.letters:
            worst = max((abs(r["eoffset_mm"][a] * 1e6 - clean["offset_nm"][a][k])
                         for r, k in compared), default=float("nan"))
            inc[a] = worst / 1000.0
            bound[a] = clean["step_nm"][a] / 1000.0
            if not worst <= clean["step_nm"][a] + clean["nm_per_count"][a]:
                ok = False
        before = rec.idx.get(at - 1)
        # the flags of the event itself: its first FLAG_SAMPLES samples
        near = [r for r in window if r["sample"] < at + FLAG_SAMPLES]
        flags = _flags(near + [x for x, k in compared if "box" not in x
                               and k < at + FLAG_SAMPLES], before, clean["status"])
        row = {"scenario": name, "where": "linuxcnc", "at": at, "until": end,
               "increase_um": inc, "bound_um": bound, "flags": flags}
        ok &= _event_checks(name, at, raw, rec, window, before, detail)
        row["ok"] = ok
        row["detail"] = "; ".join(detail) or f"samples {at}-{end - 1}"
        if not ok:
            problems.append(f"{name} at sample {at}: increase "
                            + ", ".join(f"{a} {inc[a]:.3f}" for a in rec.letters)
                            + " um (bound " + ", ".join(f"{bound[a]:.3f}" for a in rec.letters)
                            + f" um + 1 count); {row['detail']}")
        rows.append(row)
    return rows


def _moved_nm(a: dict, b: dict, letter: str) -> float:
    return abs(a["eoffset_mm"][letter] - b["eoffset_mm"][letter]) * 1e6


def _event_checks(name: str, at: int, raw: dict, rec: _Records, window: list[dict],
                  before: dict | None, detail: list[str]) -> bool:
    """What each event must also show besides the bound (so the bound is not met by luck)."""
    ok = True
    if name == "forged line":
        forged = [r for r in raw.get("records", []) if r.get("phase") == "forged"
                  and r["sample"] == at]
        here = rec.idx.get(at)
        if not forged or here is None:
            detail.append("the forged line was not injected")
            return False
        moved = {a: _moved_nm(forged[0], here, a) / 1000.0 for a in rec.letters}
        taken = all(m > 0.5 * rec.nm_per_count / 1000.0 for m in moved.values())
        detail.append("the forged line (+60 um) moved the offsets "
                      + ", ".join(f"{a} {moved[a]:.3f}" for a in rec.letters) + " um"
                      + ("" if taken else ": NOT taken"))
        ok &= taken
    elif name.startswith("power cut"):
        cut = [r for r in window if r["sample"] <= at + 1]
        zero = [r for r in raw.get("records", []) if r.get("phase") == "zero_after_cut"
                and "box" not in r and at < r["sample"]]
        held = before is not None and all(_moved_nm(r, before, a) <= MOVED_NM
                                          for r in cut for a in rec.letters)
        no_ref = any(r["box"]["status"] & (1 << 13) for r in cut)
        replied = bool(zero) and zero[0].get("reply", "").startswith("$OK,ZERO")
        # or the component gave the box its kept state back (LOAD, RESUME): its datum goes on
        # (the old sequence continues after the cut) and the operator has nothing to touch off
        resumed = bool(zero) and "skipped" in zero[0] and any(
            r["box"]["seq"] > (before or {}).get("box", {}).get("seq", 1 << 32)
            and r["box"]["status"] & (1 << 11) for r in window)
        what = (zero[0].get("reply") or zero[0].get("skipped")) if zero else "not sent"
        detail.append(f"box NO_REF {'yes' if no_ref else 'NO'}, offsets held "
                      f"{'yes' if held else 'NO'}, ZERO at {zero[0]['sample'] if zero else '-'}"
                      f" ({what}; awaiting-zero before "
                      f"it: {'yes' if zero and zero[0]['awaiting_zero_before'] else 'no'})")
        ok &= held and no_ref and (replied or resumed)
    elif name == "watchdog restart":
        r = rec.idx.get(at)
        resumed = (r is not None and before is not None
                   and r["box"]["seq"] == before["box"]["seq"] + 1
                   and bool(r["box"]["status"] & (1 << 8)))
        detail.append(f"seq {before['box']['seq'] if before else '?'} -> "
                      f"{r['box']['seq'] if r else '?'}, WDT_RESET "
                      f"{'yes' if r and r['box']['status'] & (1 << 8) else 'NO'}")
        ok &= resumed
    elif name == "reconnect":
        down = [r for r in window if r["phase"] == "link_down"]
        lost = sum(1 for r in down if not r["box"].get("delivered", True))
        dropped = any(not r["connected"] for r in down)
        detail.append(f"link down for {lost} box line(s), component saw it: "
                      f"{'yes' if dropped else 'NO'}")
        ok &= dropped and lost == len(down) > 0
    elif name == "garbage on the wire":
        r = rec.idx.get(at)
        refused = r is not None and before is not None and r["bad-lines"] > before["bad-lines"]
        detail.append(f"bad lines +{r['bad-lines'] - before['bad-lines'] if refused else 0}")
        ok &= refused
    return ok


def _box_against_twin(rec: _Records, clean: dict, cuts: tuple[int, ...]) -> dict:
    """The box's lines as the tap decoded them against the twin's clean lines, on every
    sample before the first power cut (a watchdog restart resumes bit for bit)."""
    stop = min(cuts, default=len(clean["status"]))
    compared = mismatches = 0
    for r in rec.records:
        if r["sample"] >= stop:
            continue
        compared += 1
        want = clean["corr_nm"][r["sample"]]
        mask = ~(1 << 8)  # WDT_RESET: set after the watchdog restart only
        if r["box"]["corr_nm"] != want or (r["box"]["status"] & mask) != (
                clean["status"][r["sample"]] & mask):
            mismatches += 1
    return {"compared": compared, "mismatches": mismatches}


def fault_rows(summary: dict) -> list[dict]:
    """One row per controller event of a session's summary (``run_session``), for the fault
    campaign: {scenario, where, increase_um, bound_um, flags, ok, detail}."""
    keys = ("scenario", "where", "increase_um", "bound_um", "flags", "ok", "detail")
    return [{k: row[k] for k in keys} for row in summary.get("events", [])]


def judge(raw: dict, nm_per_count: float = 1.0, step_nm: float = 60_000.0,
          clean: dict | None = None, events: list[tuple[str, int]] | None = None) -> Result:
    """Compare LinuxCNC's offsets with the box's lines, and (given the clean run's offsets,
    ``clean_reference``) each controller event with the clean run; the summary and the
    problems found."""
    problems: list[str] = []
    rec = _Records([r for r in raw.get("records", []) if "box" in r],
                   raw.get("base_pos_mm", {}), nm_per_count)
    cuts = tuple(at for name, at in events or [] if name.startswith("power cut"))
    tracked, max_off, max_joint = _tracking(rec, problems, cuts)
    holds = _open_thermocouple(rec, step_nm, problems)
    holds += _stale_pauses(raw, rec, problems)
    holds += _corrupted_lines(rec, problems)
    resync_holds, resync = _machine_off_on(rec, problems)
    holds += resync_holds
    holds += _enable_off_on(rec, problems)
    zero = _zero(raw, rec, problems)
    rows = _judge_events(raw, rec, clean, events or [], problems) if clean else []
    twin = _box_against_twin(rec, clean, cuts) if clean else {}
    if twin.get("mismatches"):
        problems.append(f"the box's own lines differ from the twin's clean lines on "
                        f"{twin['mismatches']} of {twin['compared']} samples before the first "
                        "power cut: the clean reference is not the box's")
    if not raw.get("ok"):
        problems.insert(0, f"the LinuxCNC session did not complete: {raw.get('error')}")
    records = rec.records
    summary = {"samples": len(records), "tracked_samples": tracked,
               "max_abs_diff_nm": max_off, "max_abs_diff_counts": max_off / nm_per_count,
               "max_abs_joint_diff_nm": max_joint, "holds": holds, "resync": resync,
               "zero": zero, "zero_ok": bool(zero.get("ok")), "events": rows,
               "box_vs_twin": twin,
               "bad_lines": records[-1]["bad-lines"] if records else 0,
               "lost_lines": records[-1]["lost-lines"] if records else 0,
               "ok": not problems, "problems": problems}
    return Result(summary, raw, problems)


# --- probing in service (issue 42) ----------------------------------------------------------
# The probe's resolution: the slow touch's travel in one servo period ([PROBE]SLOW_FEED 3 mm/min
# x [EMCMOT]SERVO_PERIOD 1 ms = 50 nm), plus one count of the offset (1 nm).
PROBE_RESOLUTION_NM = 3.0 / 60.0 * 1e-3 * 1e6 + 1.0


def _probe_records(raw: dict) -> tuple[dict | None, list[dict]]:
    recs = raw.get("records", [])
    ref = next((r for r in recs if r.get("phase") == "probe_ref"), None)
    return ref, [r for r in recs if r.get("phase") == "probe"]


def judge_probes(raw: dict, setup, scenario: Scenario, static: dict) -> dict:
    """Each probe against the truth and the box's twin, and updated against static.

    - the reading: the remaining error the probe measured (sign x the probed change since the
      reference touch, minus the correction LinuxCNC applied) equals the simulated truth (the
      run's drift since the reference touch minus that correction) within
      PROBE_RESOLUTION_NM, and the component sent sign x the probed change (within a count);
    - the box's answer ($M: verdict, reason, innovation, bias, variance) and its lines after
      every reading equal the twin's (hil.expect with the readings the component sent,
      codegen.estimator inside: bit-exact);
    - the chip (+``chip_um`` on the artifact) is refused (GATE), the offset does not move
      during its probe, and the box's lines are the same as if it had never been sent;
    - the tool's remaining error over the run (from the first probe on) is lower updated
      than static (the twin without readings, through the component's rules)."""
    import numpy as np

    from cnc import thermalcomp
    from contract import protocol
    from contract.fixed_point import CODE_MAX, CODE_MIN
    from hil.expect import expect_session, sr_timeline

    problems: list[str] = []
    ref, probes = _probe_records(raw)
    out: dict = {"problems": problems, "rows": [], "resolution_nm": PROBE_RESOLUTION_NM}
    if ref is None or not probes:
        problems.append("probing: the reference touch or the probes did not run")
        return out
    names = list(setup.model["axes"])
    box_axis = dict(AXES)[PROBE_AXIS]
    ai = names.index(box_axis)
    letter = PROBE_AXIS
    drift = drift_nm(setup)
    samples = {r["sample"]: r for r in raw.get("records", []) if "box" in r}
    period_s = float(setup.model["sample_period_s"])
    chip = scenario.chip_sample()
    meas: dict[int, list[tuple[int, int, int, bool]]] = {}
    rows = out["rows"]
    for p in probes:
        k = p["sample"]
        row: dict = {"sample": k, "time_h": k * period_s / 3600.0, "chip": k == chip,
                     "error": p.get("error", "")}
        rows.append(row)
        if p.get("error"):
            problems.append(f"probe at sample {k}: LinuxCNC reported {p['error']}")
        # the probed position contains the external offset (LinuxCNC 2.9): its change is the
        # drift's, the remaining error is that minus the correction applied
        dp_nm = (p["probed_mm"][2] - ref["probed_mm"][2]) * 1e6
        corr_nm = SIGN * p["eoffset_before_mm"] * 1e6  # the correction LinuxCNC applied
        row["measured_um"] = (SIGN * dp_nm - corr_nm) / 1000.0  # the remaining error seen
        row["true_um"] = (drift[k] - corr_nm) / 1000.0
        row["static_um"] = (drift[k] - SIGN * static["offset_nm"][letter][k]) / 1000.0
        row["probe_s"] = p.get("probe_s")
        # a chip on the artifact is touched chip_um early: the tool looks that much shorter
        truth = row["true_um"] - (scenario.chip_um if k == chip else 0.0) * -SIGN
        off = abs(row["measured_um"] - truth) * 1000.0
        row["measure_ok"] = off <= PROBE_RESOLUTION_NM
        if not row["measure_ok"]:
            problems.append(f"probe at sample {k}: measured {row['measured_um']:.4f} um, the "
                            f"true remaining error is {truth:.4f} um ({off:.1f} nm apart, "
                            f"resolution {PROBE_RESOLUTION_NM:g} nm)")
        if len(p["meas_sent"]) != 1 or len(p["meas_replies"]) != 1:
            problems.append(f"probe at sample {k}: sent {p['meas_sent']}, box answered "
                            f"{p['meas_replies']} (one MEAS and one $M expected)")
            continue
        _, axis_s, nm_s, seq_s = p["meas_sent"][0].split()
        axis, nm, seq = int(axis_s), int(nm_s), int(seq_s)
        row.update({"reading_um": nm / 1000.0, "seq": seq})
        want_nm = SIGN * dp_nm
        if axis != ai or seq != samples[k]["box"]["seq"] or abs(nm - want_nm) > 1.0 + 1e-6:
            problems.append(f"probe at sample {k}: sent MEAS {axis} {nm} {seq}, expected axis "
                            f"{ai}, seq {samples[k]['box']['seq']}, {want_nm:.1f} nm (sign x "
                            "the probed change)")
        meas[k + 1] = [(axis, nm, k, False)]
        reply = protocol.decode(p["meas_replies"][0])
        row["reply"] = reply
        row.update({"applied": reply.applied, "reason": reply.reason,
                    "innovation_um": None if reply.innovation_nm is None
                    else reply.innovation_nm / 1000.0,
                    "bias_um": None if reply.bias_nm is None else reply.bias_nm / 1000.0})
        pins_ok = (bool(p["meas-applied"]) == reply.applied
                   and bool(p["meas-refused"]) != reply.applied
                   and p["meas-reason"] == thermalcomp.MEAS_REASON_CODES.get(reply.reason or "",
                                                                              0)
                   and p["innovation-nm"] == (reply.innovation_nm or 0)
                   and p["bias-nm"] == (reply.bias_nm or 0))
        if not pins_ok:
            problems.append(f"probe at sample {k}: the component's pins (applied "
                            f"{p['meas-applied']}, reason {p['meas-reason']}, innovation "
                            f"{p['innovation-nm']}, bias {p['bias-nm']}) do not show "
                            f"{p['meas_replies'][0]}")
        if k == chip:
            moved = abs(p["eoffset_after_mm"] - p["eoffset_before_mm"]) * 1e6
            row["chip_moved_nm"] = moved
            if reply.applied or reply.reason != "GATE" or moved > MOVED_NM:
                problems.append(f"the chip (+{scenario.chip_um:g} um) at sample {k}: "
                                f"{p['meas_replies'][0]}, the offset moved {moved:.3f} nm "
                                "(want: refused, GATE, not moved)")
    # the twin with the readings the component sent, and without the chip's
    feed = setup.feed
    n = feed.n_samples
    codes = np.clip(np.asarray(feed.codes, dtype=np.int64), CODE_MIN, CODE_MAX)
    sr = sr_timeline(n, codes.shape[1], [])

    def twin(readings: dict):
        return expect_session(setup.twin, codes, feed.aux, sr, setup.output, zero_before=[0],
                              zero_at_powerup=setup.build.zero_at_powerup, meas=readings)

    upd = twin(meas)
    replies = [r["reply"] for r in rows if "reply" in r]
    twin_replies = list(upd.meas_replies)
    out["twin_replies_equal"] = bool(replies) and replies == twin_replies
    if replies != twin_replies:
        bad = [(r["sample"], r["reply"], t) for r, t in zip(
            [r for r in rows if "reply" in r], twin_replies, strict=False) if r["reply"] != t]
        problems.append(f"the box's answers differ from the twin's ({len(replies)} answers, "
                        f"{len(twin_replies)} from the twin, {len(bad)} differ; first: "
                        f"{bad[0] if bad else '-'})")
    mism = [k for k, r in samples.items() if r["box"]["corr_nm"] != [int(v) for v in
                                                                       upd.out_nm[k]]]
    out["box_vs_twin"] = {"compared": len(samples), "mismatches": len(mism)}
    if mism:
        problems.append(f"the box's lines differ from the twin's with the readings on "
                        f"{len(mism)} of {len(samples)} samples (first: {mism[0]})")
    if chip is not None and chip + 1 in meas:
        without = twin({i: v for i, v in meas.items() if i != chip + 1})
        same = bool(np.array_equal(without.out_nm, upd.out_nm))
        out["chip_changed_nothing"] = same
        if not same:
            problems.append("the chip's reading changed the box's output (twin with and "
                            "without it differ)")
    # the tool's remaining error, static against updated, from the first probe on
    first = probes[0]["sample"]
    ks = [k for k in sorted(samples) if k >= first]
    upd_err = [drift[k] - SIGN * samples[k]["eoffset_mm"][letter] * 1e6 for k in ks]
    st_err = [drift[k] - SIGN * static["offset_nm"][letter][k] for k in ks]

    def rms(v: list[float]) -> float:
        return math.sqrt(sum(x * x for x in v) / len(v)) / 1000.0 if v else float("nan")

    out.update({"static_rms_um": rms(st_err), "updated_rms_um": rms(upd_err),
                "static_max_um": max(map(abs, st_err), default=0.0) / 1000.0,
                "updated_max_um": max(map(abs, upd_err), default=0.0) / 1000.0,
                "samples": len(ks), "probes": len(probes),
                "applied": sum(1 for r in rows if r.get("applied")),
                "refused": sum(1 for r in rows if r.get("applied") is False)})
    if not out["updated_rms_um"] < out["static_rms_um"]:
        problems.append(f"updated ({out['updated_rms_um']:.3f} um RMS) is not better than "
                        f"static ({out['static_rms_um']:.3f} um RMS)")
    for r in rows:
        r.pop("reply", None)
    return out


def probe_table(pr: dict) -> list[str]:
    """The residual at each probe, static against updated (um, the box's sign)."""
    lines = ["", f"probing in service: Z, the reference touched right after ZERO, a probe every "
             f"{pr.get('every', '?')} samples (um; residual = drift since the reference - "
             "correction applied)",
             f"{'probe':>5s} {'time h':>7s} {'static':>8s} {'updated':>8s} {'true':>8s}"
             f"{'reading':>9s} {'innov.':>8s} {'bias':>8s}  answer",
             "-" * 78]
    for i, r in enumerate(pr.get("rows", [])):
        ans = ("applied" if r.get("applied") else f"refused {r.get('reason')}"
               if "applied" in r else "-") + ("  (chip +50 um)" if r.get("chip") else "")

        def f(v: float | None) -> str:
            return f"{v:8.3f}" if v is not None else f"{'-':>8s}"
        lines.append(f"{i:5d} {r['time_h']:7.2f} {f(r['static_um'])} {f(r['measured_um'])} "
                     f"{f(r['true_um'])} {f(r.get('reading_um'))} {f(r.get('innovation_um'))} "
                     f"{f(r.get('bias_um'))}  {ans}")
    if "static_rms_um" in pr:
        lines += [f"tool error from the first probe on ({pr['samples']} samples): static "
                  f"{pr['static_rms_um']:.3f} um RMS (max {pr['static_max_um']:.3f}), updated "
                  f"{pr['updated_rms_um']:.3f} um RMS (max {pr['updated_max_um']:.3f}); "
                  f"{pr['applied']} applied, {pr['refused']} refused",
                  f"each reading = the true remaining error within "
                  f"{pr['resolution_nm']:g} nm: "
                  f"{'yes' if all(r.get('measure_ok') for r in pr['rows']) else 'NO'}; "
                  f"box = twin (answers {'yes' if pr.get('twin_replies_equal') else 'NO'}, "
                  f"lines {pr['box_vs_twin']['compared'] - pr['box_vs_twin']['mismatches']}/"
                  f"{pr['box_vs_twin']['compared']})"
                  + ("" if "chip_changed_nothing" not in pr else
                     f"; the chip changed nothing: "
                     f"{'yes' if pr['chip_changed_nothing'] else 'NO'}")]
    return lines


def short_testplan() -> ThermalTestPlan:
    """A time-compressed thermal test for LinuxCNC: the step protocol in 2 s steps (2000 to
    8000 rpm), 8 s running and 4 s cooling, a measurement every 2 s with a 0.5 s stop, the
    logger on digital output 0 (``M64 P0``): 7 measurements, 12.5 s."""
    prog = build_program("step", 8000.0, hours=8 / 3600, cool_hours=4 / 3600,
                         step_minutes=2 / 60)
    return ThermalTestPlan(prog, 2.0, 0.5, "M64 P0", "linuxcnc")


def short_mcode_testplan() -> ThermalTestPlan:
    """The user M-code trigger (``M100 P<k>``, cnc/config/mcodes/M100): 4 s at 6000 rpm, 2 s
    cooling, a measurement every 2 s with a 0.5 s stop: 4 measurements, 6.5 s."""
    prog = build_program("constant", 8000.0, hours=4 / 3600, cool_hours=2 / 3600)
    return ThermalTestPlan(prog, 2.0, 0.5, "M100", "linuxcnc")


def default_testplans() -> tuple[ThermalTestPlan, ...]:
    return (short_testplan(), short_mcode_testplan())


def _state_at(events: list[dict], pin: str, t: float) -> object:
    value = None
    for e in events:
        if e["t"] > t:
            break
        if e["pin"] == pin:
            value = e["value"]
    return value


def judge_program(plan: ThermalTestPlan, rec: dict | None, tol_s: float = 0.25) -> dict:
    """The program as LinuxCNC ran it (pin changes against wall time) against the plan's
    schedule: a trigger pulse at every measurement time, spindle stopped and oriented then,
    and the protocol's speed in every running window. Time 0 is the first trigger."""
    problems: list[str] = []
    out: dict = {"trigger": plan.trigger, "measurements_expected": plan.n_intervals + 1,
                 "problems": problems}
    if not rec:
        problems.append("the test program was not run")
        return out
    if rec.get("error"):
        problems.append(f"LinuxCNC reported an error running {plan.trigger} test program: "
                        f"{rec['error']}")
    ev = rec["events"]
    rises = [e["t"] for i, e in enumerate(ev) if e["pin"] == "trigger" and e["value"]
             and _state_at(ev[:i], "trigger", e["t"]) in (False, None)]
    falls = [e["t"] for e in ev if e["pin"] == "trigger" and e["value"] is False]
    out["measurements_found"] = len(rises)
    if len(rises) != plan.n_intervals + 1:
        problems.append(f"{len(rises)} trigger pulses, the plan has {plan.n_intervals + 1}")
        return out
    numbers = [e.get("number") for e in ev if e["pin"] == "trigger" and e["value"]]
    if plan.digital_output is None and numbers != [f"{k}" for k in range(len(rises))] and \
            [float(n) for n in numbers] != [float(k) for k in range(len(rises))]:
        problems.append(f"the M-code got measurement numbers {numbers}")
    t0 = rises[0]
    expected = plan.measurement_times_s()
    errors = [abs((r - t0) - e) for r, e in zip(rises, expected, strict=True)]
    widths = [f - r for r, f in zip(rises, [f for f in falls if f > t0], strict=False)]
    out["max_trigger_error_s"] = max(errors)
    out["pulse_s"] = [round(w, 3) for w in widths]
    if max(errors) > tol_s:
        problems.append(f"a trigger came {max(errors):.3f} s off its scheduled time "
                        f"(tolerance {tol_s} s)")
    if plan.digital_output is not None and any(abs(w - plan.measure_s) > tol_s
                                               for w in widths):
        problems.append(f"trigger pulses of {widths} s, the stop is {plan.measure_s} s")
    bad_stop = [k for k, r in enumerate(rises)
                if _state_at(ev, "on", r + 0.01) or not _state_at(ev, "oriented", r + 0.01)]
    out["stopped_and_oriented"] = len(rises) - len(bad_stop)
    if bad_stop:
        problems.append(f"measurements {bad_stop}: spindle not stopped and oriented")
    p, d = plan.measure_every_s, plan.measure_s
    checked, wrong = 0, []
    for k in range(plan.n_intervals):
        mid = k * p + d + (p - d) / 2  # the middle of interval k's running window
        want = float(plan.program.rpm_at(k * p + (p - d) / 2))
        on = bool(_state_at(ev, "on", t0 + mid))
        got = float(_state_at(ev, "speed", t0 + mid) or 0.0) if on else 0.0
        checked += 1
        if abs(got - want) > 0.5:
            wrong.append((k, want, got))
    out["speeds_checked"], out["speeds_wrong"] = checked, wrong
    out["speeds"] = sorted({float(plan.program.rpm_at(k * p)) for k in range(plan.n_intervals)})
    if wrong:
        problems.append(f"spindle speed off the schedule in intervals (k, want, got) {wrong}")
    return out


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
    result = judge(raw, step_nm=1000.0 * setup.model["sample_period_s"],
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

    ap = argparse.ArgumentParser(prog="python -m cnc", description=__doc__.split("\n\n")[0])
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

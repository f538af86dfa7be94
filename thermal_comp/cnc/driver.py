#!/usr/bin/python3
"""Headless LinuxCNC session for `make cnc` and the CI test: LinuxCNC's [DISPLAY] program.

LinuxCNC starts this as its user interface (``<this> -ini <file>``); it exits with this
program's status. It plays the operator and the machine's surroundings, and records:

- starts the native firmware (the box) and sits on the box's serial line as a *tap*: the box's
  pty on one side, a second pty (symlinked at the component's configured port) on the other,
  so the component reads a real pty exactly like /dev/ttyUSB0 while every byte the box sent is
  kept, independently of the component, for the comparison;
- puts the machine on, homes it, moves to a start position and feeds the run sample by sample
  (the box's feed channel, docs/native-board.md), with the faults of the plan: an open
  thermocouple (``F <ch> 01``), a stale stream (feeding pauses), a corrupted line (the tap
  flips one digit), machine off/on, ZERO (``thermalcomp.zero``);
- after each sample waits until the component has taken the line and LinuxCNC's external
  offset has settled, then reads ``axis.L.eoffset``, ``joint.N.motor-pos-cmd`` and the
  component's status pins through HAL;
- optionally runs an NC program in AUTO and records the spindle speed, orient and trigger pins;
- probing in service (issue 42, the plan's ``probe``): before each sample it moves the
  simulated artifact's surface with the run's thermal drift (``artifact.in0``, probe_sim.hal),
  touches the reference right after the job's ZERO (``o<probe_ref> call [0]``) and every N
  samples calls the probing subroutine (``o<probe_ref> call [1]``, MDI), which hands the
  reading to the component; it records the probed position, the offsets, the component's
  MEAS pins and the box's ``$M`` answer (one probe with a chip on the artifact: +50 um).

It judges nothing: it writes everything to the plan's results file; cnc/session.py compares.
Runs under Debian's /usr/bin/python3 (``linuxcnc`` and ``hal`` modules) with the standard
library only, plus the project's stdlib-only wire-protocol decoder.
"""

from __future__ import annotations

import json
import random
import sys
import time
import traceback
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

import hal  # noqa: E402  (LinuxCNC's modules: /usr/bin/python3 only)
import linuxcnc  # noqa: E402

from thermal_comp.cnc.machine import COMP, Machine  # noqa: E402  (LinuxCNC's side)
from thermal_comp.cnc.tap import Box, DriverError, Tap  # noqa: E402
from thermal_comp.contract import protocol  # noqa: E402  (stdlib only: docs/architecture.md, floor 0)


def _pulse_zero(machine: Machine, tap: Tap, timeout: float) -> str:
    """The operator's touch-off: ``thermalcomp.zero`` up until the box answers, then down."""
    with tap.cond:
        n = len(tap.replies)
    machine.setp(f"{COMP}.zero", 1)
    tap.wait(lambda: any(r.startswith(("$OK,ZERO", "$E")) for r in tap.replies[n:]), timeout,
             "the box's reply to ZERO")
    machine.setp(f"{COMP}.zero", 0)
    return next(r for r in tap.replies[n:] if r.startswith(("$OK,ZERO", "$E")))


def start_box(plan: dict, warm: bool) -> Box:
    """The box always runs with its retained memory in a file (the backup SRAM): a warm start
    (``--wdt-reset``) resumes from it; a cold one (a power cut) finds none."""
    retain = Path(plan["retain"])
    if not warm:
        retain.unlink(missing_ok=True)  # no backup battery: the power cut took it
    return Box(plan["firmware"], ("--wdt-reset",) * warm + ("--retain", str(retain)))


def restart_box(plan: dict, boxes: list[Box], tap: Tap, warm: bool,
                faults: dict[int, int]) -> None:
    """Kill the box between two samples and start it again; the tap attaches to its new pty
    (the component's end of the line stays). The chips' faults are physical: they are still
    there after the restart."""
    tap.detach_box()
    boxes[-1].kill()
    box = start_box(plan, warm)
    boxes.append(box)
    tap.attach_box(box.pty)
    for ch, sr in sorted(faults.items()):
        if sr:
            box.feed(f"F {ch} {sr:02x}\n")


def garbage(seed: int, n_random: int = 512, run: int = 16 * 1024) -> bytes:
    """Noise on the wire: random bytes (newlines among them), then ``run`` bytes without one."""
    rng = random.Random(seed)
    no_newline = bytes(b for b in range(256) if b != 0x0A)
    return rng.randbytes(n_random) + bytes(rng.choice(no_newline) for _ in range(run))


def forged_line(box_line: dict, delta_nm: int) -> bytes:
    """A CRC-valid ``$C`` line with the next seq and every correction moved by ``delta_nm``."""
    return protocol.encode_sample((box_line["seq"] + 1) % (1 << 32), box_line["status"],
                                  [c + delta_nm for c in box_line["corr_nm"]],
                                  box_line["temps"])


_MEAS_PINS = ("meas-applied", "meas-refused", "meas-reason", "meas-nm", "meas-seq", "meas-count",
              "meas-refusals", "meas-refused-in-row")


def probe_touch(machine: Machine, tap: Tap, probe: dict, mode: int, sample: int,
                chip_mm: float = 0.0) -> dict:
    """Call the probing subroutine in MDI (mode 0: the reference touch, 1: a reading) and
    record what it did: the probed position (``linuxcnc.stat().probed_position``), the
    offsets LinuxCNC applied before and after, the line the component sent, the box's
    answer and the component's MEAS pins."""
    letter = probe["axis"]
    with tap.cond:
        n_cmd, n_rep = len(tap.commands), len(tap.replies)
    if chip_mm:
        hal.set_p("artifact.in1", repr(chip_mm))  # a chip on the artifact, for this touch
    before = machine.snapshot()
    t0 = time.monotonic()
    machine.mdi_polled(f"o<{probe['sub']}> call [{mode}]", 30.0)
    error = _drain_errors(machine)
    if error:
        raise DriverError(f"the probing subroutine at sample {sample}: {error}")
    if mode == 1:
        tap.wait(lambda: any(r.startswith(("$M", "$E")) for r in tap.replies[n_rep:]), 5.0,
                 "the box's answer to MEAS")
    if chip_mm:
        hal.set_p("artifact.in1", "0")
    machine.mdi(probe["return_mdi"])
    s = machine.poll()
    with tap.cond:
        sent = [c for c in tap.commands[n_cmd:] if c.startswith("MEAS")]
        replies = [r for r in tap.replies[n_rep:] if r.startswith(("$M", "$E"))]
    rec = {"sample": sample, "phase": "probe_ref" if mode == 0 else "probe",
           "probed_mm": list(s.probed_position)[:3], "probe_tripped": bool(s.probe_tripped),
           "drift_mm": machine.get("artifact.in0"), "chip_mm": chip_mm,
           "eoffset_before_mm": before["eoffset_mm"][letter],
           "request_before_mm": before["request_mm"][letter],
           "pos_cmd_before_mm": before["pos_cmd_mm"][letter],
           "meas_sent": sent, "meas_replies": replies, "probe_s": time.monotonic() - t0,
           "error": _drain_errors(machine)}
    after = machine.snapshot()
    rec["eoffset_after_mm"] = after["eoffset_mm"][letter]
    rec.update({pin: machine.get(f"{COMP}.{pin}") for pin in _MEAS_PINS})
    rec.update({f"{pin}": machine.get(f"{COMP}.{letter}.{pin}")
                for pin in ("bias-nm", "innovation-nm", "p-nm2")})
    return rec


def _drain_errors(machine: Machine) -> str:
    """LinuxCNC's errors since the last call (its DEBUG and MSG texts are not errors)."""
    errors = []
    while True:
        err = machine.errors.poll()
        if not err:
            return "; ".join(errors)
        if err[0] in (linuxcnc.NML_ERROR, linuxcnc.OPERATOR_ERROR):
            errors.append(str(err[1]).strip())


def replay(plan: dict, machine: Machine, boxes: list[Box], tap: Tap,
           records: list[dict] | None = None) -> list[dict]:
    """Feed every sample, apply the plan's events, record what LinuxCNC does after each."""
    run = _Replay(plan, machine, boxes, tap, records if records is not None else [])
    for k, line in enumerate(Path(plan["feed"]).read_text().splitlines()):
        run.sample(k, line)
    return run.records


class _Replay:
    """One replay: the plan's events by sample, the boxes, the tap and the records so far."""

    def __init__(self, plan: dict, machine: Machine, boxes: list[Box], tap: Tap,
                 records: list[dict]) -> None:
        self.plan, self.machine, self.boxes, self.tap, self.records = (plan, machine, boxes,
                                                                       tap, records)
        ev = plan.get("events", {})
        self.ev = ev
        self.cuts = {c["at"]: c for c in ev.get("power_cut", [])}  # the box boots cold
        self.zero_after_cut = {c["at"] + int(c["zero_after"]): c for c in self.cuts.values()}
        self.faults: dict[int, int] = {}
        self.timeout = float(plan.get("timeout_s", 10.0))
        self.probe = plan.get("probe")
        self.probe_at = set(self.probe["at"]) if self.probe else set()
        self.chips = ({int(k): float(v) for k, v in self.probe.get("chips", {}).items()}
                      if self.probe else {})

    def sample(self, k: int, line: str) -> None:
        machine = self.machine
        if self.probe:
            # the machine's thermal drift at this sample moves the artifact's surface
            hal.set_p("artifact.in0", repr(float(self.probe["drift_mm"][k])))
        # before any injection: garbage is counted as soon as the component reads it
        bad_before = machine.get(f"{COMP}.bad-lines")
        if k == 0 and self.plan.get("zero_at_start"):
            self.zero_at_start(k)
        phase = self.before(k)
        link = self.ev.get("reconnect")
        link_down = bool(link and link["at"] <= k < link["at"] + link["samples"])
        phase = self.link_events(k, phase, link_down)
        box_line = self.feed(k, line, phase, bad_before, link_down)
        phase = self.after(k, phase)
        _settle(machine, self.timeout, k)
        self.records.append({"sample": k, "phase": phase, "box": box_line,
                             **machine.snapshot()})
        forged = self.ev.get("forged")
        if forged and k == forged["at"]:
            self.forge(k, box_line, int(forged["delta_nm"]))
        if k in self.probe_at:
            self.records.append(probe_touch(machine, self.tap, self.probe, 1, k,
                                            self.chips.get(k, 0.0)))

    def zero_at_start(self, k: int) -> None:
        """A start-referenced box holds (NO_REF) until ZERO: the job's touch-off."""
        machine, timeout = self.machine, self.timeout
        self.records.append({"sample": k, "phase": "zero_start",
                             "reply": _pulse_zero(machine, self.tap, timeout)})
        if self.probe:
            # the reference touch right after ZERO (the offsets are 0)
            machine.wait(lambda: all(abs(machine.get(f"axis.{a}.eoffset")) < 1e-9
                                     for a in machine.letters), timeout,
                         "the offsets at 0 after ZERO")
            self.records.append(probe_touch(machine, self.tap, self.probe, 0, k))

    def before(self, k: int) -> str:
        """The events before sample k is fed; the sample's phase."""
        ev, machine, boxes, phase = self.ev, self.machine, self.boxes, "track"
        open_tc, stale, bad = ev.get("open"), ev.get("stale"), ev.get("bad_line")
        off, zero, dis = ev.get("machine_off"), ev.get("zero"), ev.get("disable")
        if open_tc and k in (open_tc["at"], open_tc["stop"]):
            self.faults[open_tc["channel"]] = 1 if k == open_tc["at"] else 0
            boxes[-1].feed(f"F {open_tc['channel']} {self.faults[open_tc['channel']]:02x}\n")
        if open_tc and open_tc["at"] <= k < open_tc["stop"]:
            phase = "open"
        if stale and k == stale["at"]:
            # the box goes quiet: nothing is fed for pause_s of wall time
            before = machine.snapshot()
            time.sleep(float(stale["pause_s"]))
            self.records.append({"sample": k, "phase": "stale_pause", "before": before,
                                 "during": machine.snapshot()})
        if bad and k == bad["at"]:
            self.tap.corrupt_next, phase = True, "bad_line"
        if off and k == off["at"]:
            machine.off()
        if off and off["at"] <= k < off["at"] + off["samples"]:
            phase = "machine_off"
        if dis and k == dis["at"]:
            machine.setp(f"{COMP}.enable", 0)  # the operator switches compensation off
        if dis and dis["at"] <= k < dis["at"] + dis["samples"]:
            phase = "disabled"
        if zero and k == zero["at"]:
            acks = machine.get(f"{COMP}.zero-acks")
            self.records.append({"sample": k, "phase": "zero_sent", "zero_acks_before": acks,
                                 "reply": _pulse_zero(machine, self.tap, self.timeout)})
            phase = "zero"
        return self.restarts(k, phase)

    def restarts(self, k: int, phase: str) -> str:
        wdt = self.ev.get("wdt_restart")
        if wdt and k == wdt["at"]:
            restart_box(self.plan, self.boxes, self.tap, True, self.faults)
            phase = "wdt_restart"
        if k in self.cuts:
            restart_box(self.plan, self.boxes, self.tap, False, self.faults)
            phase = "power_cut"
        if k in self.zero_after_cut:
            self.zero_after_power_cut(k, int(self.zero_after_cut[k]["zero_after"]))
            phase = "zero_after_cut"
        return phase

    def zero_after_power_cut(self, k: int, after: int) -> None:
        """The operator's touch-off some samples after the box came back cold. ZERO after 1 is
        the race of a touch-off before the component has even seen the restart: sent as it
        is. Later, the operator looks once the component has settled the restart: a touch-off
        only if it awaits one, not once it gave the box its kept state back and the box
        resumed (docs/linuxcnc.md, "Power cuts")."""
        machine = self.machine
        rec: dict = {"sample": k, "phase": "zero_after_cut"}
        if after > 1:
            machine.wait(lambda: not machine.get(f"{COMP}.restoring"), self.timeout,
                         "the component to give the box its state back")
        rec["awaiting_zero_before"] = machine.get(f"{COMP}.awaiting-zero")
        if after <= 1 or rec["awaiting_zero_before"]:
            rec["reply"] = _pulse_zero(machine, self.tap, self.timeout)
        else:
            rec["skipped"] = "the box resumed its kept state: no touch-off needed"
        self.records.append(rec)

    def link_events(self, k: int, phase: str, link_down: bool) -> str:
        """Garbage on the wire, the cable pulled and plugged in again."""
        machine, noise, link = self.machine, self.ev.get("garbage"), self.ev.get("reconnect")
        if noise and k == noise["at"]:
            self.tap.inject(garbage(int(noise.get("seed", 41))))
            phase = "garbage"
        if link and k == link["at"]:
            self.tap.drop_link()  # the cable is pulled: the component's reads fail
            machine.wait(lambda: not machine.get(f"{COMP}.connected"), self.timeout,
                         "the component to notice the dropped link")
        if link_down:
            phase = "link_down"
        if link and k == link["at"] + link["samples"]:
            self.tap.restore_link()  # plugged in again: the same port name, a new device
            machine.wait(lambda: machine.get(f"{COMP}.connected"), 20,
                         "the component to reopen the port and read INFO")
            phase = "reconnected"
        return phase

    def feed(self, k: int, line: str, phase: str, bad_before: int, link_down: bool) -> dict:
        """Sample k to the box; wait until the component took (or refused) its line."""
        machine, tap, timeout, forged = self.machine, self.tap, self.timeout, self.ev.get("forged")
        n_before = len(tap.samples)
        holds = machine.get(f"{COMP}.holds")
        self.boxes[-1].feed(line + "\n")
        tap.wait(lambda n=n_before: len(tap.samples) > n, timeout,
                 f"the box's line of sample {k}")
        box_line = tap.samples[n_before]
        if link_down:
            time.sleep(0.01)  # nothing reaches the component
        elif box_line["corrupted"] or phase == "garbage" or (forged and k == forged["at"] + 1):
            # refused, swallowed by the noise before it, or taken as the forged line's stray
            machine.wait(lambda b=bad_before: machine.get(f"{COMP}.bad-lines") > b, timeout,
                         f"the component to count a bad line at sample {k}")
            if phase == "garbage":
                time.sleep(0.1)  # the rest of the run and the box's line it swallowed
            if forged and k == forged["at"] + 1:
                machine.wait(lambda s=box_line["seq"]: machine.get(f"{COMP}.seq") == s,
                             timeout, f"the component to take seq {box_line['seq']} "
                             f"(sample {k})")
        else:
            seq = box_line["seq"]
            # taken (seq) or held (a line whose seq went back: a restarted box)
            machine.wait(lambda s=seq, h=holds: machine.get(f"{COMP}.seq") == s or
                         machine.get(f"{COMP}.holds") > h, timeout,
                         f"the component to take seq {seq} (sample {k})")
        return box_line

    def after(self, k: int, phase: str) -> str:
        """Machine on and compensation on again, after their last sample off."""
        machine, off, dis = self.machine, self.ev.get("machine_off"), self.ev.get("disable")
        if off and k == off["at"] + off["samples"] - 1:
            machine.on()
            # LinuxCNC put the old offset into the program position at machine-off; the next
            # move (here: back to the start position) takes it out again
            machine.wait(lambda: machine.get(f"{COMP}.active"), self.timeout,
                         "the component to resynchronise after machine-on")
            machine.mdi(self.plan["start_mdi"])
            phase = "machine_on"
        if dis and k == dis["at"] + dis["samples"] - 1:
            machine.setp(f"{COMP}.enable", 1)
            machine.wait(lambda: machine.get(f"{COMP}.active"), self.timeout,
                         "the component to resynchronise after enable")
            phase = "enabled"
        return phase

    def forge(self, k: int, box_line: dict, delta_nm: int) -> None:
        """Between this sample and the next: one extra line, CRC-valid, delta_nm off."""
        machine = self.machine
        fake = forged_line(box_line, delta_nm)
        self.tap.inject(fake)
        machine.wait(lambda s=(box_line["seq"] + 1) % (1 << 32):
                     machine.get(f"{COMP}.seq") == _s32(s), self.timeout,
                     "the component to take the forged line")
        _settle(machine, self.timeout, k)
        self.records.append({"sample": k, "phase": "forged", "line": fake.decode().strip(),
                             **machine.snapshot()})


def _s32(value: int) -> int:
    return value - (1 << 32) if value >= 1 << 31 else value


def _settle(machine: Machine, timeout: float, k: int) -> None:
    if machine.poll().task_state == linuxcnc.STATE_ON:
        time.sleep(0.003)  # let motion pick up a counts change written this instant
        machine.wait(machine.settled, timeout, f"the external offset to settle after "
                     f"sample {k}")


def run_program(prog: dict, machine: Machine) -> dict:
    """Run an NC program in AUTO and record the spindle and trigger pins against wall time.

    The trigger is a HAL pin (``M64 P<n>``: ``motion.digital-out-NN``) or the log a user
    M-code writes (``M100``: wall-clock time and measurement number per line)."""
    # spindle.0.orient is up for a servo period only (the sim loops it to is-oriented);
    # spindle.0.locked holds from the completed orient until the next M3/M4/M5
    pins = {"speed": "spindle.0.speed-out", "oriented": "spindle.0.locked",
            "on": "spindle.0.on"}
    if prog.get("trigger_pin"):
        pins["trigger"] = prog["trigger_pin"]
    machine.cmd.mode(linuxcnc.MODE_AUTO)
    machine.cmd.wait_complete()
    machine.cmd.program_open(prog["path"])
    machine.cmd.wait_complete()
    events: list[dict] = []
    errors: list[str] = []
    last: dict[str, object] = {}
    while machine.errors.poll():  # drop what an earlier step left
        pass
    machine.cmd.auto(linuxcnc.AUTO_RUN, 0)
    t0, wall0 = time.monotonic(), time.time()
    deadline = t0 + float(prog["timeout_s"])
    started = False
    while True:
        now = time.monotonic()
        for name, pin in pins.items():
            value = machine.get(pin)
            if last.get(name) != value:
                events.append({"t": now - t0, "pin": name, "value": value})
                last[name] = value
        err = machine.errors.poll()
        if err:
            errors.append(str(err[1]))
        s = machine.poll()
        if s.interp_state != linuxcnc.INTERP_IDLE:
            started = True
        elif started or now - t0 > 2.0:
            break
        if now > deadline:
            raise DriverError(f"the program {prog['path']} did not finish within "
                              f"{prog['timeout_s']} s")
        time.sleep(0.002)
    if prog.get("trigger_log"):
        log = Path(prog["trigger_log"])
        calls = [line.split() for line in log.read_text().splitlines()] if log.is_file() else []
        for stamp, number in calls:
            # an M-code call is an instant: a pulse of one millisecond
            events += [{"t": float(stamp) - wall0, "pin": "trigger", "value": True,
                        "number": number},
                       {"t": float(stamp) - wall0 + 0.001, "pin": "trigger", "value": False}]
        events.sort(key=lambda e: e["t"])
    if machine.poll().state == linuxcnc.RCS_ERROR and not errors:
        errors.append("RCS_ERROR")
    return {"path": prog["path"], "events": events, "elapsed_s": time.monotonic() - t0,
            "error": "; ".join(errors)}


def main(argv: list[str]) -> int:
    ini_path = argv[argv.index("-ini") + 1] if "-ini" in argv else None
    if ini_path is None:
        print("driver: started without -ini <file> (LinuxCNC passes it)", file=sys.stderr)
        return 2
    ini = linuxcnc.ini(ini_path)
    plan_path = Path(ini_path).resolve().parent / ini.find("THERMALCOMP", "DRIVER_PLAN")
    plan = json.loads(plan_path.read_text())
    out: dict = {"ok": False, "error": "", "records": [], "programs": []}
    boxes: list[Box] = []
    tap = None
    t_start = time.monotonic()
    try:
        letters = [a["letter"] for a in plan["axes"]]
        machine = Machine(letters)
        boxes.append(start_box(plan, warm=False))
        tap = Tap(boxes[0].pty, Path(plan["port_link"]))
        machine.wait(lambda: machine.get(f"{COMP}.connected"), 20,
                     "the component to open the port and read INFO")
        machine.on()
        machine.home()
        machine.mdi(plan["start_mdi"])
        out["base_pos_mm"] = {a: machine.get(f"joint.{machine.joint[a]}.motor-pos-cmd")
                              for a in letters}
        replay(plan, machine, boxes, tap, out["records"])  # kept when it stops half-way
        for prog in plan.get("programs", []):
            out["programs"].append(run_program(prog, machine))
        out["ok"] = True
    except Exception as exc:  # the session reports why it stopped; session.py fails it
        out["error"] = f"{type(exc).__name__}: {exc}"
        out["traceback"] = traceback.format_exc()
    finally:
        if tap is not None:
            out["box_samples"] = tap.samples
            out["box_replies"] = tap.replies
            out["commands"] = tap.commands
            out["line_times"] = tap.times
            tap.close()
        if boxes:
            out["box_exit"] = boxes[-1].stop()
            out["box_stderr"] = boxes[-1].stderr()
            out["box_starts"] = len(boxes)
        out["elapsed_s"] = time.monotonic() - t_start
        Path(plan["results"]).write_text(json.dumps(out))
    return 0 if out["ok"] else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

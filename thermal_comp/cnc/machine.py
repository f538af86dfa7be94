"""LinuxCNC as the `make cnc` driver sees it (cnc/driver.py): machine on and off, homing, MDI,
HAL pins, and a snapshot of the offsets and the component's pins after each sample. Needs
LinuxCNC's ``linuxcnc`` and ``hal`` modules (Debian's /usr/bin/python3)."""

from __future__ import annotations

import subprocess
import time

import hal
import linuxcnc

from thermal_comp.cnc.tap import DriverError

COMP = "thermalcomp"
# LinuxCNC's offset planner stops within a few hundredths of a nanometre of the request
SETTLED_MM = 1e-7


class Machine:
    """LinuxCNC through its Python interface, plus HAL reads and writes."""

    def __init__(self, letters: list[str]) -> None:
        self.cmd, self.stat = linuxcnc.command(), linuxcnc.stat()
        self.errors = linuxcnc.error_channel()
        self.letters = letters
        self.joint = {"x": 0, "y": 1, "z": 2}
        self.probe = hal.component("tcdriver")  # hal.get_value needs a component of ours
        self.probe.ready()

    def poll(self):
        self.stat.poll()
        return self.stat

    def wait(self, pred, timeout: float, what: str) -> None:
        deadline = time.monotonic() + timeout
        while not pred():
            if time.monotonic() > deadline:
                raise DriverError(f"timed out after {timeout:g} s waiting for {what}")
            time.sleep(0.002)

    def on(self) -> None:
        self.cmd.state(linuxcnc.STATE_ESTOP_RESET)
        self.cmd.wait_complete()
        self.cmd.state(linuxcnc.STATE_ON)
        self.cmd.wait_complete()
        self.wait(lambda: self.poll().task_state == linuxcnc.STATE_ON, 10, "machine on")

    def off(self) -> None:
        self.cmd.state(linuxcnc.STATE_OFF)
        self.cmd.wait_complete()
        # after OFF task_state reads ESTOP_RESET, never OFF: wait for "not on"
        self.wait(lambda: self.poll().task_state != linuxcnc.STATE_ON, 10, "machine off")

    def home(self) -> None:
        self.cmd.mode(linuxcnc.MODE_MANUAL)
        self.cmd.wait_complete()
        self.cmd.home(-1)
        self.cmd.wait_complete()
        self.wait(lambda: all(self.poll().homed[:3]), 20, "homing")

    def mdi(self, line: str) -> None:
        self.cmd.mode(linuxcnc.MODE_MDI)
        self.cmd.wait_complete()
        self.cmd.mdi(line)
        self.cmd.wait_complete(30)
        self.wait(lambda: self.poll().interp_state == linuxcnc.INTERP_IDLE, 30, f"MDI {line}")

    def mdi_polled(self, line: str, timeout: float) -> None:
        """MDI without ``wait_complete`` while it runs: that call keeps Python's GIL, so the
        tap's thread could not carry the component's MEAS to the box while the probing
        subroutine waits (M66) for the answer. Polls the status instead."""
        self.cmd.mode(linuxcnc.MODE_MDI)
        self.cmd.wait_complete()
        self.cmd.mdi(line)
        serial = self.cmd.serial
        self.wait(lambda: self.poll().echo_serial_number >= serial and
                  self.stat.interp_state == linuxcnc.INTERP_IDLE, timeout, f"MDI {line}")

    def get(self, pin: str):
        return hal.get_value(pin)

    def setp(self, pin: str, value: object) -> None:
        subprocess.run(["halcmd", "setp", pin, str(value)], check=True)

    def settled(self) -> bool:
        """The offsets have reached their requests and the joints' commanded positions stood
        still for 3 servo periods. The servo thread is not realtime here (uspace without an RT
        kernel) and can stall for milliseconds, so periods are counted by its heartbeat
        (``motion.servo.last-period`` changes every period), not by the wall clock."""
        if not all(abs(self.get(f"axis.{a}.eoffset") - self.get(f"axis.{a}.eoffset-request"))
                   < SETTLED_MM for a in self.letters):
            return False
        pos = [self.get(f"joint.{self.joint[a]}.motor-pos-cmd") for a in self.letters]
        beat, beats = self.get("motion.servo.last-period"), 0
        deadline = time.monotonic() + 2.0
        while beats < 3 and time.monotonic() < deadline:
            time.sleep(0.0005)
            now = self.get("motion.servo.last-period")
            if now != beat:
                beat, beats = now, beats + 1
            if [self.get(f"joint.{self.joint[a]}.motor-pos-cmd") for a in self.letters] != pos:
                return False
        return beats >= 3

    def snapshot(self) -> dict:
        snap = {"eoffset_mm": {a: self.get(f"axis.{a}.eoffset") for a in self.letters},
                "request_mm": {a: self.get(f"axis.{a}.eoffset-request") for a in self.letters},
                "pos_cmd_mm": {a: self.get(f"joint.{self.joint[a]}.motor-pos-cmd")
                               for a in self.letters},
                "comp_offset_mm": {a: self.get(f"{COMP}.{a}.offset") for a in self.letters}}
        snap["bias_nm"] = {a: self.get(f"{COMP}.{a}.bias-nm") for a in self.letters}
        for pin in ("holding", "fault", "stale", "walking", "extrapolating", "referenced",
                    "active", "seq", "bad-lines", "lost-lines", "holds", "zero-acks",
                    "age-s", "status", "restarts", "awaiting-zero", "connected",
                    "model-mismatch"):
            snap[pin] = self.get(f"{COMP}.{pin}")
        return snap

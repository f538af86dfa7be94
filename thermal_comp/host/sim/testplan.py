"""The NC program that runs a thermal test on a real machine (``host testplan``), as in paper 002.

The spindle runs the protocol's speed schedule (``host.sim.spindle_programs``, the same schedule
``host simulate`` uses) and every ``measure_every`` it stops, orients (M19) so the test bar
always faces the gap sensors the same way, triggers the logger with a configurable M-code and
dwells while the measurement is taken, then resumes. Timeline, from cycle start:

  [0, d)                   reference measurement of the cold machine (M19, trigger, G4 d)
  [d + kP, d + kP + P - d)  interval k: spindle at the scheduled speed (schedule time t = tau - d)
  [(k+1)P, (k+1)P + d)     stop (M5), orient (M19), trigger, dwell d: measurement k+1

so the measurements are taken at tau = 0, P, 2P, ... and the spindle runs the schedule except
during the d-second stops. The program moves no axis: the operator positions the test bar at
the sensor nest before cycle start (the header comment says so). It ends with M5 and M30.

Dwell words differ between controls: ``rs274`` (LinuxCNC, Haas, RS274/NGC) writes ``G4 P<s>.``
in seconds; ``fanuc`` writes ``G4 X<s>.`` (Fanuc reads P as milliseconds). ``linuxcnc`` dwells
like rs274 and takes a trigger LinuxCNC can do without a PLC: ``M64 P<n>`` sets digital output
n (``motion.digital-out-NN``) for each measurement stop and ``M65 P<n>`` clears it after the
dwell, so the logger sees a pulse as long as the stop; or a user M-code M100-M199 (an executable
file found through ``[RS274NGC]USER_M_PATH``), called as ``M1xx P<k>`` with the measurement
number k (the file gets it as its first argument). It orients with ``M19 R0``: LinuxCNC 2.9
does nothing on a bare ``M19``.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

from thermal_comp.contract import __version__
from thermal_comp.contract.errors import InputError
from thermal_comp.host.sim.spindle_programs import COOL, SpindleProgram

DIALECTS = ("rs274", "fanuc", "linuxcnc")
LINUXCNC_USER_M = range(100, 200)  # LinuxCNC runs user M-codes M100..M199 only
LINUXCNC_DIO = range(64)  # motmod num_dio is at most 64 (default 4: P0..P3)
RESERVED_M = {0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 19, 30, 98, 99}
MAX_DWELL_S = 99999.0  # Fanuc's G4 X limit
_TRIGGER = re.compile(r"M(\d{1,4})(?:\s*P(\d{1,2}))?")
_DURATION = re.compile(r"^\s*(\d+(?:\.\d*)?|\.\d+)\s*(s|sec|m|min|h|hr|hours?)?\s*$", re.I)


class PlanError(InputError):
    """The test cannot be written as asked (cadence, trigger, schedule that does not fit)."""


def parse_duration(text: str | float, what: str) -> float:
    """'300', '300s', '5min', '5m', '1.5h' to seconds."""
    if isinstance(text, int | float):
        seconds = float(text)
    else:
        m = _DURATION.match(str(text))
        if not m:
            raise PlanError(f"{what}: cannot read duration {text!r} (e.g. 300s, 5min, 1h)")
        unit = (m.group(2) or "s").lower()
        scale = 1.0 if unit.startswith("s") else 60.0 if unit.startswith("m") else 3600.0
        seconds = float(m.group(1)) * scale
    if not (math.isfinite(seconds) and seconds > 0):
        raise PlanError(f"{what}: duration must be positive (got {text!r})")
    return seconds


def _clock(seconds: float) -> str:
    s = round(seconds)
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}"


def _num(seconds: float) -> str:
    """A dwell value with a decimal point (so no control reads it as milliseconds)."""
    return f"{seconds:.3f}".rstrip("0")


@dataclass(frozen=True)
class ThermalTestPlan:
    """A spindle program plus the measurement cadence, rendered as G-code by ``render``."""

    program: SpindleProgram
    measure_every_s: float = 300.0
    measure_s: float = 10.0
    trigger: str = "M100"
    dialect: str = "rs274"
    program_number: int = 1000

    def __post_init__(self) -> None:
        if self.dialect not in DIALECTS:
            raise PlanError(f"unknown dialect '{self.dialect}' (known: {', '.join(DIALECTS)})")
        self._trigger()  # refuses a trigger the dialect's control cannot do
        if not 1 <= self.program_number <= 9999:
            raise PlanError(f"program number O{self.program_number} is not in 1..9999")
        p, d = self.measure_every_s, self.measure_s
        if d >= p:
            raise PlanError(f"measurement stop {d:g} s does not fit in --measure-every "
                                f"{p:g} s: the spindle would never run")
        if p - d > MAX_DWELL_S:
            raise PlanError(f"--measure-every {p:g} s needs a dwell longer than the "
                                f"{MAX_DWELL_S:g} s a control accepts")
        total = self.program.duration_s
        k = total / p
        if abs(k - round(k)) > 1e-9 or round(k) < 1:
            raise PlanError(
                f"the test ({total / 3600:g} h of running and cooling = {total:g} s) is not a "
                f"whole number of --measure-every {p:g} s intervals; change --hours/--cool-hours"
                " or the cadence")
        for seg in self.program.segments:
            if seg.rpm > self.program.max_rpm:
                raise PlanError(f"speed {seg.rpm:g} rpm at t = {_clock(seg.start_s)} is "
                                    f"above --max-rpm {self.program.max_rpm:g}")
            for edge in (seg.start_s, seg.end_s):
                pos = edge % p
                if p - d + 1e-9 < pos < p - 1e-9:
                    raise PlanError(
                        f"the speed changes at t = {_clock(edge)}, inside the measurement "
                        f"stop {_clock(edge - pos + p - d)}..{_clock(edge - pos + p)}; choose "
                        "a --measure-every that divides the protocol's segments")

    def _trigger(self) -> tuple[int, int | None]:
        """(M number, digital output or None) of ``trigger``, checked against the dialect."""
        m = _TRIGGER.fullmatch(self.trigger.strip().upper())
        if not m:
            forms = "M100 or M64 P0" if self.dialect == "linuxcnc" else "M100"
            raise PlanError(f"--trigger {self.trigger!r}: give an M-code such as {forms}")
        code, out = int(m.group(1)), m.group(2)
        if out is not None:
            if code != 64 or self.dialect != "linuxcnc":
                raise PlanError(f"--trigger {self.trigger!r}: 'M64 P<n>' (LinuxCNC's digital "
                                "output) is the only trigger with a P word, and only with "
                                "--dialect linuxcnc")
            if int(out) not in LINUXCNC_DIO:
                raise PlanError(f"--trigger {self.trigger!r}: LinuxCNC has digital outputs "
                                f"P0..P{LINUXCNC_DIO[-1]} (motmod num_dio)")
            return code, int(out)
        if self.dialect == "linuxcnc" and code not in LINUXCNC_USER_M:
            raise PlanError(f"--trigger {self.trigger}: LinuxCNC runs user M-codes M100-M199 "
                            "only (an executable file in [RS274NGC]USER_M_PATH); or use "
                            "'M64 P<n>', a digital output")
        if code in RESERVED_M:
            raise PlanError(f"--trigger {self.trigger}: M{code} already means "
                                "something to the control (spindle, coolant, program end); "
                                "use a free M-code wired to the logger")
        return code, None

    @property
    def digital_output(self) -> int | None:
        """The LinuxCNC digital output the trigger sets (``M64 P<n>``), or None."""
        return self._trigger()[1]

    def _trigger_on(self, k: int, note: str) -> str:
        code, out = self._trigger()
        if out is not None:
            return f"M64 P{out} (MEASUREMENT {k} {note})"
        if self.dialect == "linuxcnc":
            return f"M{code} P{k} (MEASUREMENT {k} {note})"
        return f"M{code} (MEASUREMENT {k} {note})"

    def _trigger_off(self) -> list[str]:
        _, out = self._trigger()
        return [f"M65 P{out}"] if out is not None else []

    def _trigger_words(self) -> str:
        code, out = self._trigger()
        if out is not None:
            return f"M64 P{out} SETS DIGITAL OUTPUT {out} FOR THE STOP, M65 P{out} CLEARS IT"
        if self.dialect == "linuxcnc":
            return f"M{code} P<K> TRIGGERS THE LOGGER, K = MEASUREMENT NUMBER"
        return f"M{code} TRIGGERS THE LOGGER"

    @property
    def n_intervals(self) -> int:
        return round(self.program.duration_s / self.measure_every_s)

    def measurement_times_s(self) -> list[float]:
        """Trigger times from cycle start: the reference, then one per interval."""
        return [k * self.measure_every_s for k in range(self.n_intervals + 1)]

    @property
    def duration_s(self) -> float:
        """Cycle time: reference measurement + the whole schedule."""
        return self.measure_s + self.program.duration_s

    def _orient(self) -> str:
        # LinuxCNC 2.9 ignores a bare M19 (no orient, spindle.0.locked stays low): give R
        return "M19 R0" if self.dialect == "linuxcnc" else "M19"

    def _dwell(self, seconds: float) -> str:
        word = "X" if self.dialect == "fanuc" else "P"
        return f"G4 {word}{_num(seconds)}"

    def render(self) -> str:
        """The NC program text (ends with a newline)."""
        prog, p, d = self.program, self.measure_every_s, self.measure_s
        out = [
            "%",
            f"O{self.program_number:04d} (THERMAL TEST {prog.protocol.upper()})",
            f"(GENERATED BY HOST TESTPLAN {__version__}, PAPER 002 / ISO 230-3 PROCEDURE)",
            f"(MAX SPINDLE {prog.max_rpm:g} RPM, RUN {prog.run_s / 3600:g} H, COOL "
            f"{(prog.duration_s - prog.run_s) / 3600:g} H)",
            f"(MEASURE EVERY {p:g} S: M5, M19, {self._trigger_words()}, G4 {d:g} S)",
            f"({self.n_intervals + 1} MEASUREMENTS, CYCLE TIME {_clock(self.duration_s)})",
            "(NO AXIS MOTION: PUT THE TEST BAR AT THE SENSOR NEST BEFORE CYCLE START)",
            f"(SCHEDULE, T = TIME AFTER THE {d:g} S REFERENCE MEASUREMENT)",
        ]
        for seg in prog.segments:
            what = "COOLING" if seg.phase == COOL else ("STOPPED" if seg.rpm == 0 else "RUN")
            out.append(f"(T {_clock(seg.start_s)} - {_clock(seg.end_s)} S{seg.rpm:.0f} {what})")
        out += ["G21 G90 G17 G40 G80 G94", "M5", self._orient(),
                self._trigger_on(0, "AT T 0:00:00, COLD REFERENCE"), self._dwell(d),
                *self._trigger_off()]
        running, oriented = False, True
        for k in range(self.n_intervals):
            start, stop = k * p, k * p + p - d
            out.append(f"(INTERVAL {k + 1}, T {_clock(start)} - {_clock(stop)})")
            edges = sorted({start, stop, *[s.start_s for s in prog.segments
                                           if start < s.start_s < stop]})
            for a, b in zip(edges[:-1], edges[1:], strict=True):
                rpm = float(prog.rpm_at(a))
                if rpm > 0 and not running:
                    out.append(f"M3 S{rpm:.0f}")
                    running, oriented = True, False
                elif rpm > 0:
                    out.append(f"S{rpm:.0f}")  # a new segment: the speed changes on the fly
                elif running:
                    out.append("M5")
                    running = False
                out.append(self._dwell(b - a))
            if running:
                out.append("M5")
                running = False
            if not oriented:
                out.append(self._orient())
                oriented = True
            out.append(self._trigger_on(k + 1, f"AT T {_clock(stop)}"))
            out.append(self._dwell(d))
            out += self._trigger_off()
        out += ["M5", "M30 (END OF THERMAL TEST)", "%"]
        return "\n".join(out) + "\n"

    def write(self, path: str | Path) -> Path:
        """Write the program atomically (temp file, then rename)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(self.render())
        tmp.replace(path)
        return path

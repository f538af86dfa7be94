#!/usr/bin/python3
"""thermalcomp: a LinuxCNC userspace HAL component that puts the box's corrections on external
offsets (docs/linuxcnc.md).

It reads the box's serial stream (docs/protocol.md) from a serial port (/dev/ttyUSB0 on a real
machine, a pseudo-terminal in the tests), checks every line's CRC and sequence number with the
project's own decoder, maps box axes to LinuxCNC axes with the sign and count size of a small
config file (cnc/config/thermalcomp.conf) and drives ``axis.L.eoffset-counts/-scale/-enable/
-clear``. Rules (issue 41: no single event may make the tool error worse than the clean run by
more than one step limit of an axis; where the component cannot know, it holds and says why):

- **the expected model**: the config names the box's model (``[box] model = model.json``, or
  ``model_hash`` with a ``max_step_um`` per axis). Until the box's INFO reports that hash, and
  whenever it reports another one (or the config names none), every axis holds, ``fault`` and
  ``model-mismatch`` say so and the log names both hashes.
- **hold**: while the box reports MODEL_BAD, HOLD, CLAMP, NO_DATA, IMPLAUSIBLE, NO_REF or BEYOND,
  while the stream is stale (no sample line for ``stale_periods`` sample periods), on a line
  that fails its CRC or does not decode, on an over-long line (``MAX_LINE_BYTES`` without a
  newline) and on a line whose ``seq`` goes back until a second line confirms a restart, every
  axis keeps the offset it has.
- **bounded moves**: per sample line an axis offset moves by at most min(the model's step
  limit of that axis, ``slew_nm_per_s`` x the sample period), and never beyond
  ``max_abs_um`` (the box's clamp, 200 um). A forged or damaged-but-CRC-valid line therefore
  moves the tool by one step limit at most, and the next good line moves it back. The only
  exception is the datum change right after the box acknowledges a ZERO the component sent,
  which still stays within ``max_abs_um``.
- **machine off**: LinuxCNC drops the external offset (and its ``eoffset-request``) when the
  machine goes off but keeps the counts pin, because it reads counts as a change; when the
  machine is on and homed again the component resynchronises: it adds (wanted -
  round(request / scale)) to its counts, so the offset lands on the box's value, not on the
  value before plus the change. The same resync runs after ``enable`` comes back (while
  ``enable`` is false it asserts ``eoffset-clear``: LinuxCNC ramps the offset to 0).
- **box restart** (``seq`` goes back, confirmed by the next line): the component asks INFO
  again and holds until it matches. A box without a reference walks from 0 at its slew
  limit (SLEW): the component holds until the box tracks again, then walks to it. A box that
  comes back without its reference (NO_REF, or REFERENCED from a new power-up datum) while
  offsets are applied: the component holds its last offsets (never walks to 0) until ZERO;
  after that ZERO it applies held offset + the box's change since then (a per-axis base).
  A warm reset of the box (seq continues, WDT_RESET) is followed like any line.
- ``zero`` (rising edge, e.g. from the touch-off macro) sends the box ``ZERO``: from the next
  sample the box outputs the change since then; that first value is a new datum and
  is applied without the step limit (LinuxCNC still ramps it at OFFSET_AV_RATIO). An
  ``$OK,ZERO`` the component did not ask for changes nothing.
- **probing in service** (issue 42, ``[probe]``): ``meas-request`` (rising edge, from the
  probing subroutine's ``M64``) turns ``meas-mm`` (the probed position's change since the
  reference touch, machine units) and the external offset LinuxCNC applies into the axis's
  displacement since the reference as the probe saw it, and sends ``MEAS <axis> <nm> <seq>``
  with the seq of the latest sample line; the box's ``$M`` answer (applied, or refused with a
  reason) goes to ``meas-done``/``meas-applied``/``meas-refused``/``meas-reason`` and the
  axis's ``L.bias-nm``/``L.innovation-nm``. The reading never moves an offset itself: the
  box adds its estimate to its output, which reaches LinuxCNC through the step limits above.

Runs under Debian's /usr/bin/python3 (where LinuxCNC's ``hal`` module lives); needs only the
standard library and the project's stdlib-only wire-protocol decoder, found next to this file
(the repository root, or a copy of ``cnc/`` and the decoder's package side by side).
"""

from __future__ import annotations

import argparse
import configparser
import math
import os
import signal
import sys
import termios
import time
from dataclasses import dataclass, field
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from cnc.keptstate import StateKeeper  # noqa: E402  (stdlib + contract, like this file)
from contract import model_file, protocol  # noqa: E402  (stdlib only: docs/architecture.md)
from contract.box import DEFAULT_AXIS_STEP_UM_PER_S  # noqa: E402
from contract.errors import InputError  # noqa: E402
from contract.tilt import unit_of  # noqa: E402

NAME = "thermalcomp"
_S = protocol.Status  # the status bits have one home: contract/protocol.py
MODEL_BAD, HOLD, SLEW, CLAMP = int(_S.MODEL_BAD), int(_S.HOLD), int(_S.SLEW), int(_S.CLAMP)
NO_DATA, EXTRAP, REFERENCED = int(_S.NO_DATA), int(_S.EXTRAP), int(_S.REFERENCED)
IMPLAUSIBLE, NO_REF, BEYOND = int(_S.IMPLAUSIBLE), int(_S.NO_REF), int(_S.BEYOND)
# the box says: do not trust this sample. CLAMP: the box's value is not the model's.
HOLD_BITS = MODEL_BAD | HOLD | CLAMP | NO_DATA | IMPLAUSIBLE | NO_REF | BEYOND
UNITS_MM = {"mm": 1.0, "inch": 25.4}
SEQ_MOD = 1 << 32
# The box's clamp, BOX_MAX_CORRECTION_NM in firmware/include/box_config.h (checked by
# tests/test_thermalcomp.py): the default of [box] max_abs_um.
DEFAULT_MAX_ABS_UM = 200.0
# A receive buffer this long without a newline is discarded up to the next newline (a box line
# is at most a few hundred bytes): a stream without newlines must not grow memory or read time.
MAX_LINE_BYTES = 4096
OVERLONG = b"<over-long line>"  # what Port.read_lines returns for a discarded over-long line
# meas-reason: 0 applied (or nothing yet); 1.. the box's refusals (contract.protocol.MEAS_REASONS,
# in that order); then the component's own: the request never reached the box, or no answer.
MEAS_LOCAL_REASONS = ("NO_PROBE", "LINK", "RANGE", "TIMEOUT", "BAD_ARG")
MEAS_REASON_CODES = {r: i + 1 for i, r in enumerate(protocol.MEAS_REASONS
                                                   + MEAS_LOCAL_REASONS)}


class ConfigError(ValueError):
    """The component's config file is missing or wrong (names the file, section and key)."""


@dataclass
class AxisMap:
    """One LinuxCNC axis driven by one box axis."""

    letter: str  # LinuxCNC axis letter, lower case (pin names axis.<letter>.eoffset-*)
    box_axis: str  # name in the box's INFO axis list (the model's target, e.g. dz_um)
    sign: int  # +1: LinuxCNC offset = +correction; -1: offset = -correction
    nm_per_count: float  # size of one eoffset count in nanometres
    step_nm: float | None = None  # the model's step limit of this axis per sample line (nm)
    index: int | None = None  # position in the box's sample line (from INFO)
    base: int = 0  # counts added to the box's value: the offset held over a cold box restart
    want: int = 0  # offset the component wants, in counts
    sent: int = 0  # the offset LinuxCNC has been told (counts) since the last resync
    seen: bool = False  # a value from the box has been applied since start
    box_nm: int = 0  # the box's last correction for this axis
    bias_nm: int = 0  # the box's in-service estimate for this axis (its last $M answer)
    innovation_nm: int = 0  # the last reading's innovation (reading - (model + bias))
    p_nm2: int = 0  # the estimate's variance after the last answer


@dataclass
class Config:
    port: str
    baud: int = 115200
    stale_periods: float = 3.0
    period_s: float | None = None  # None: the box's INFO period
    slew_nm_per_s: float = 1000.0
    units_mm: float = 1.0  # machine units in mm (LINEAR_UNITS)
    settle_s: float = 0.05  # wait after machine-on/enable before reading eoffset-request
    poll_s: float = 0.002
    axes: list[AxisMap] = field(default_factory=list)
    model_hash: str | None = None  # the hash the box's INFO must report (None: refuse to drive)
    model_path: Path | None = None  # where model_hash and the step limits came from
    max_abs_um: float = DEFAULT_MAX_ABS_UM  # no offset ever beyond this (the box's clamp)
    resume: bool = True  # after a power cut ask the box to RESUME its kept state (no: ZERO)
    keep_state: bool = True  # SNAP after each sample with a datum; LOAD it back after a cut
    state_file: Path | None = None  # where that block is also kept (survives this process)
    probe_axis: str | None = None  # [probe] axis: the LinuxCNC axis the probe measures
    probe_timeout_s: float = 2.0  # no $M answer within this: TIMEOUT
    probed_includes_offset: bool = True  # LinuxCNC 2.9: #5063 contains the external offset


def load_config(path: str | Path) -> Config:
    """Read the component's config file (INI syntax, see cnc/config/thermalcomp.conf)."""
    path = Path(path)
    parser = configparser.ConfigParser(inline_comment_prefixes=("#", ";"))
    if not parser.read(path):
        raise ConfigError(f"{path}: component config not found or unreadable")

    def get(section: str, key: str, kind: type, default: object = None) -> object:
        if not parser.has_option(section, key):
            if default is None:
                raise ConfigError(f"{path}: [{section}] needs '{key}'")
            return default
        text = parser.get(section, key)
        try:
            return kind(text)
        except ValueError:
            raise ConfigError(f"{path}: [{section}] {key} = {text!r} is not a valid "
                              f"{kind.__name__}") from None

    if not parser.has_section("box"):
        raise ConfigError(f"{path}: no [box] section (port, stale_periods, ...)")
    units = str(get("machine", "units", str, "mm")) if parser.has_section("machine") else "mm"
    if units not in UNITS_MM:
        raise ConfigError(f"{path}: [machine] units = {units!r}: mm or inch")
    period = get("box", "period_s", float, -1.0)
    cfg = Config(port=str(get("box", "port", str)), baud=int(get("box", "baud", int, 115200)),
                 stale_periods=float(get("box", "stale_periods", float, 3.0)),
                 period_s=None if period == -1.0 else float(period),
                 slew_nm_per_s=float(get("box", "slew_nm_per_s", float, 1000.0)),
                 units_mm=UNITS_MM[units],
                 settle_s=float(get("box", "settle_s", float, 0.05)),
                 poll_s=float(get("box", "poll_s", float, 0.002)))
    for name, value, lo in (("stale_periods", cfg.stale_periods, 1.0),
                            ("slew_nm_per_s", cfg.slew_nm_per_s, 1e-9),
                            ("poll_s", cfg.poll_s, 1e-4)):
        if not (math.isfinite(value) and value >= lo):
            raise ConfigError(f"{path}: [box] {name} = {value:g} must be at least {lo:g}")
    if cfg.period_s is not None and not cfg.period_s > 0:
        raise ConfigError(f"{path}: [box] period_s = {cfg.period_s:g} must be positive")
    cfg.max_abs_um = float(get("box", "max_abs_um", float, DEFAULT_MAX_ABS_UM))
    resume = str(get("box", "resume", str, "yes")).strip().lower()
    if resume not in ("yes", "no"):
        raise ConfigError(f"{path}: [box] resume = {resume!r}: yes or no")
    cfg.resume = resume == "yes"
    keep = str(get("box", "keep_state", str, "yes")).strip().lower()
    if keep not in ("yes", "no"):
        raise ConfigError(f"{path}: [box] keep_state = {keep!r}: yes or no")
    cfg.keep_state = keep == "yes"
    if parser.has_option("box", "state_file"):
        kept = Path(parser.get("box", "state_file").strip())
        cfg.state_file = kept if kept.is_absolute() else path.resolve().parent / kept
    if not (math.isfinite(cfg.max_abs_um) and cfg.max_abs_um > 0):
        raise ConfigError(f"{path}: [box] max_abs_um = {cfg.max_abs_um:g} must be positive")
    model: dict | None = None
    if parser.has_option("box", "model"):
        model_path = Path(parser.get("box", "model").strip())
        if not model_path.is_absolute():
            model_path = path.resolve().parent / model_path  # relative to this file
        try:
            model = model_file.read_model(model_path)
        except (InputError, OSError) as exc:
            raise ConfigError(f"{path}: [box] model = {model_path}: {exc}") from None
        cfg.model_path = model_path
        cfg.model_hash = model_file.model_hash(model)
    if parser.has_option("box", "model_hash"):
        given = parser.get("box", "model_hash").strip()
        if not given:
            raise ConfigError(f"{path}: [box] model_hash is empty")
        if cfg.model_hash is not None and given != cfg.model_hash:
            raise ConfigError(f"{path}: [box] model_hash = {given} but the model "
                              f"{cfg.model_path} has hash {cfg.model_hash}: which one is it?")
        cfg.model_hash = given
    for section in parser.sections():
        if not section.startswith("axis."):
            continue
        letter = section[5:].lower()
        if letter not in "xyzabcuvw" or len(letter) != 1:
            raise ConfigError(f"{path}: [{section}]: the axis letter must be one of XYZABCUVW")
        sign_text = str(get(section, "sign", str)).strip()
        if sign_text not in ("+1", "1", "+", "-1", "-"):
            raise ConfigError(f"{path}: [{section}] sign = {sign_text!r}: +1 or -1")
        nm = float(get(section, "nm_per_count", float, 1.0))
        if not (math.isfinite(nm) and nm > 0):
            raise ConfigError(f"{path}: [{section}] nm_per_count = {nm:g} must be positive")
        box_axis = str(get(section, "box_axis", str))
        if unit_of(box_axis) != "um":
            raise ConfigError(f"{path}: [{section}] box_axis = {box_axis}: a tilt axis (urad) "
                              "is not a linear offset; only axes in um drive external offsets")
        given = (float(get(section, "max_step_um", float))
                 if parser.has_option(section, "max_step_um") else None)
        step_nm = _axis_step_nm(path, section, box_axis, model, given,
                                cfg.model_hash is not None)
        if step_nm is not None and nm > step_nm:
            raise ConfigError(f"{path}: [{section}] nm_per_count = {nm:g} is larger than the "
                              f"axis's step limit ({step_nm:g} nm per sample): one count "
                              "would already be more than the step limit")
        cfg.axes.append(AxisMap(letter, box_axis,
                                -1 if sign_text.startswith("-") else 1, nm, step_nm))
    if not cfg.axes:
        raise ConfigError(f"{path}: no [axis.<letter>] section: nothing to drive")
    letters = [a.letter for a in cfg.axes]
    if len(set(letters)) != len(letters):
        raise ConfigError(f"{path}: an axis letter appears twice ({', '.join(letters)})")
    if parser.has_section("probe"):
        axis = str(get("probe", "axis", str)).strip().lower()
        if axis not in letters:
            raise ConfigError(f"{path}: [probe] axis = {axis!r}: not one of the driven axes "
                              f"({', '.join(letters)})")
        cfg.probe_axis = axis
        cfg.probe_timeout_s = float(get("probe", "timeout_s", float, 2.0))
        try:
            cfg.probed_includes_offset = parser.getboolean("probe", "probed_includes_offset",
                                                           fallback=True)
        except ValueError:
            raise ConfigError(f"{path}: [probe] probed_includes_offset = "
                              f"{parser.get('probe', 'probed_includes_offset')!r}: yes or "
                              "no") from None
        if not (math.isfinite(cfg.probe_timeout_s) and cfg.probe_timeout_s > 0):
            raise ConfigError(f"{path}: [probe] timeout_s = {cfg.probe_timeout_s:g} must be "
                              "positive")
    return cfg


def _axis_step_nm(path: Path, section: str, box_axis: str, model: dict | None,
                  given_um: float | None, need: bool) -> float | None:
    """An axis's step limit per sample line in nm: the model's ``axes.<name>.max_step_um``
    rounded up to nm as codegen does for the box (a model without it: codegen's default, the
    box's walk-back rate x its period), or ``max_step_um`` in the axis section (the smaller
    of the two when both are given). None when neither exists and no hash is expected."""
    if given_um is not None and not (math.isfinite(given_um) and given_um > 0):
        raise ConfigError(f"{path}: [{section}] max_step_um = {given_um:g} must be positive")
    steps = [given_um * 1000.0] if given_um is not None else []
    if model is not None:
        axes = model.get("axes", {})
        if box_axis not in axes:
            raise ConfigError(f"{path}: [{section}] box_axis = {box_axis}: the model has axes "
                              f"{', '.join(axes) or '(none)'}")
        ax = axes[box_axis]
        step_um = ax["max_step_um"] if "max_step_um" in ax else (
            DEFAULT_AXIS_STEP_UM_PER_S * float(model["sample_period_s"]))
        steps.append(float(math.ceil(float(step_um) * 1000.0)))
    if not steps and need:
        raise ConfigError(f"{path}: [{section}] needs 'max_step_um' (the model's "
                          f"axes.{box_axis}.max_step_um) when [box] gives model_hash without "
                          "model = <model.json>")
    return min(steps) if steps else None


class Port:
    """The box's serial port, opened raw with the standard library (no pyserial needed)."""

    def __init__(self, path: str, baud: int) -> None:
        self.path, self.baud = path, baud
        self.fd: int | None = None
        self.buf = bytearray()
        self.synced = False  # the bytes before the first newline after opening are dropped
        self.discarding = False  # an over-long line is being dropped up to its newline

    def open(self) -> bool:
        try:
            fd = os.open(self.path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        except OSError:
            return False
        try:
            attrs = termios.tcgetattr(fd)
            attrs[0] = 0  # iflag: no CR/LF translation, no flow control
            attrs[1] = 0  # oflag: raw output
            attrs[2] = termios.CS8 | termios.CREAD | termios.CLOCAL
            attrs[3] = 0  # lflag: no echo, no canonical mode
            speed = getattr(termios, f"B{self.baud}", termios.B115200)
            attrs[4] = attrs[5] = speed
            attrs[6][termios.VMIN], attrs[6][termios.VTIME] = 0, 0
            termios.tcsetattr(fd, termios.TCSANOW, attrs)
        except termios.error:
            pass  # not a tty (a FIFO in a bench): read it as it is
        self.fd, self.buf, self.synced, self.discarding = fd, bytearray(), False, False
        return True

    def close(self) -> None:
        if self.fd is not None:
            try:
                os.close(self.fd)
            except OSError:
                pass
        self.fd = None

    def read_lines(self) -> list[bytes] | None:
        """Complete lines received so far (without CR LF); None when the port went away.

        A line that grows beyond MAX_LINE_BYTES without a newline comes out once as OVERLONG
        (as soon as it is that long) and the rest of it, up to the next newline, is dropped."""
        assert self.fd is not None
        try:
            data = os.read(self.fd, 65536)
        except BlockingIOError:
            return []
        except OSError:
            return None  # EIO: the other side (box, USB adapter) is gone
        if not data:
            return None
        return self.feed(data)

    def feed(self, data: bytes) -> list[bytes]:
        """Split received bytes into lines (read_lines without the port, for the tests)."""
        out: list[bytes] = []
        start = 0
        while (nl := data.find(b"\n", start)) >= 0:
            chunk = data[start:nl]
            start = nl + 1
            if self.discarding:
                self.discarding, self.synced = False, True
            elif not self.synced:
                self.synced = True  # the bytes before the first newline after opening
            elif len(self.buf) + len(chunk) > MAX_LINE_BYTES:
                out.append(OVERLONG)
            else:
                out.append((bytes(self.buf) + chunk).rstrip(b"\r"))
            self.buf.clear()
        rest = data[start:]
        if not self.discarding:
            if len(self.buf) + len(rest) > MAX_LINE_BYTES:
                self.discarding = True
                self.buf.clear()
                out.append(OVERLONG)
            else:
                self.buf += rest
        return out

    def write(self, data: bytes) -> bool:
        if self.fd is None:
            return False
        try:
            os.write(self.fd, data)
            return True
        except OSError:
            return False


class Compensator:
    """The component's logic, without HAL: what the pins should say after each event."""

    def __init__(self, cfg: Config, log=None) -> None:
        self.cfg = cfg
        self.log = log or (lambda msg: print(f"{NAME}: {msg}", file=sys.stderr, flush=True))
        self.info: protocol.Info | None = None
        self.info_fresh = False  # INFO answered since the port opened / the box restarted
        self.last_seq: int | None = None
        self.prev_seq: int | None = None  # the seq before last_seq (to spot a stray line)
        self.last_lost = 0  # lines counted lost when last_seq arrived
        self.suspect_seq: int | None = None  # a seq that went back, not yet confirmed
        self.last_line_t: float | None = None
        self.status = 0
        self.stream_status = 0  # status of the last in-sequence line (before a restart)
        self.bad_lines = 0
        self.lost_lines = 0
        self.restarts = 0
        self.holds = 0  # sample lines on which the offsets were held
        self.rebooted = False  # the box restarted and is still walking from 0 (SLEW)
        self.await_zero = False  # the box came back without its datum: hold until ZERO
        self.zero_pending = False  # ZERO sent, not acknowledged yet
        # after a power cut: RESUME <n> to send (n periods off), and sent but not answered
        self.resume_wanted: int | None = None
        self.resume_pending = False
        # the box's state block kept here (SNAP), given back before that RESUME (LOAD)
        self.keeper = (StateKeeper(cfg.model_hash, cfg.state_file)
                       if cfg.keep_state and cfg.resume else None)
        self.loaded = False  # the kept block was given back since the latest restart
        self.load_extra = 0  # samples after the kept block's, before the cut (RESUME runs them)
        self.cut_t: tuple[float | None, float] = (None, 0.0)
        # ZERO refused while an axis held ($E,HOLDING): sent again on the first line without a
        # hold bit, so the touch-off waiting for zero-acks happens on a datum the box can keep
        self.zero_deferred = False
        # a ZERO acknowledged while the box reported NO_REF after its seq went back (a restart
        # not yet confirmed): the held offsets are already the base, the restart must not wait
        # for another ZERO
        self.zeroed_since_suspect = False
        self.rezero = False  # ZERO acknowledged: the next value is a new datum, not a move
        self.zero_acks = 0
        self.zero_seq = -1
        self.stale = False
        self.fault = False  # the box's last line carried a hold bit
        self.walking = False
        self.hold_reason = ""  # why the last sample line was held ("" when it was applied)
        self._warned_hash: str | None = None
        # probing in service (MEAS): the request in flight and the last answer
        self.meas_pending: dict | None = None  # {"axis", "letter", "nm", "seq", "t"}
        self.meas_done = False  # the last request has its answer (applied, or refused)
        self.meas_applied = False
        self.meas_reason = ""  # "" applied; a MEAS_REASONS or MEAS_LOCAL_REASONS name
        self.meas_nm: int | None = None  # the last reading sent (nm)
        self.meas_seq: int | None = None  # ... and the sample it referred to
        self.meas_count = 0  # answers (applied or refused, local refusals included)
        self.meas_refusals = 0  # refused, in total
        self.meas_refused_in_row = 0  # refused since the last applied reading
        if cfg.model_hash is None:
            self.log("no expected model hash in the config ([box] model = <model.json> or "
                     "model_hash): every axis holds; docs/linuxcnc.md")

    def period_s(self) -> float | None:
        """The sample period the stale check counts in (wall-clock seconds)."""
        if self.cfg.period_s is not None:
            return self.cfg.period_s
        return self.info.period_ms / 1000.0 if self.info is not None else None

    @property
    def model_mismatch(self) -> bool:
        """No expected hash, or the box's INFO reported another model (or a bad model CRC)."""
        if self.cfg.model_hash is None:
            return True
        return self.info is not None and (self.info.model_hash != self.cfg.model_hash
                                          or not self.info.crc_ok)

    def needs_info(self) -> bool:
        """Ask the box INFO (again): none yet, not since a restart, or another model."""
        return self.info is None or not self.info_fresh or self.model_mismatch

    @property
    def holding(self) -> bool:
        return bool(self.fault or self.stale or self.rebooted or self.await_zero
                    or self.suspect_seq is not None or self.needs_info())

    def take_info(self, info: protocol.Info) -> None:
        missing = [a.box_axis for a in self.cfg.axes if a.box_axis not in info.axes]
        if missing:
            self.log(f"the box's model has axes {', '.join(info.axes) or '(none)'}; the config "
                     f"asks for {', '.join(missing)}: those LinuxCNC axes hold")
        for a in self.cfg.axes:
            a.index = info.axes.index(a.box_axis) if a.box_axis in info.axes else None
        if self.info is None or info != self.info:
            self.log(f"box {info.fw_version}, model {info.model_hash} (CRC "
                     f"{'OK' if info.crc_ok else 'BAD'}), {info.period_ms} ms, axes "
                     f"{';'.join(info.axes)}")
        self.info, self.info_fresh = info, True
        expected = self.cfg.model_hash
        if expected is not None and info.model_hash != expected:
            if self._warned_hash != info.model_hash:
                source = f" ({self.cfg.model_path})" if self.cfg.model_path else ""
                self.log(f"the box carries model {info.model_hash}, the config expects "
                         f"{expected}{source}: every axis holds until the box reports "
                         f"{expected}")
            self._warned_hash = info.model_hash
        else:
            self._warned_hash = None

    def _sequence(self, seq: int) -> str:
        """Judge a sample line's seq: "ok" (in order, maybe after lost lines), "suspect"
        (went back: held until the next line says whether it was a restart), "restart" (a
        second line confirms it)."""
        last = self.last_seq
        if last is None:
            self.last_seq, self.last_lost = seq, 0
            return "ok"
        gap = (seq - last) % SEQ_MOD
        if 0 < gap < SEQ_MOD // 2:
            if self.suspect_seq is not None:
                self._stray(self.suspect_seq, f"seq {self.suspect_seq} went back")
                self.suspect_seq = None
            if gap > 1:
                self.lost_lines += gap - 1
                self.log(f"{gap - 1} sample line(s) lost before seq {seq}")
            self.prev_seq, self.last_seq, self.last_lost = last, seq, gap - 1
            return "ok"
        if self.prev_seq is not None and 1 <= (seq - self.prev_seq) % SEQ_MOD <= 2:
            # the line before jumped ahead and this one continues the one before it: that
            # line was a stray (forged, or damaged and still CRC-valid); it moved one step
            self.lost_lines -= self.last_lost
            self._stray(last, f"seq {last} jumped ahead of {self.prev_seq}, {seq} follows")
            self.suspect_seq, self.last_seq, self.last_lost = None, seq, 0
            return "ok"
        if self.suspect_seq is not None and 1 <= (seq - self.suspect_seq) % SEQ_MOD <= 2:
            self.prev_seq, self.last_seq, self.last_lost = self.suspect_seq, seq, 0
            self.suspect_seq = None
            return "restart"
        self.suspect_seq, self.zeroed_since_suspect = seq, False
        return "suspect"

    def _stray(self, seq: int, why: str) -> None:
        self.bad_lines += 1
        self.log(f"sample line seq {seq} out of sequence ({why}): taken as a stray line")

    def take_sample(self, s: protocol.Sample, now: float) -> bool:
        """Apply one sample line; True when it confirmed a box restart (ask INFO again)."""
        before_t, self.last_line_t, self.status, self.stale = (self.last_line_t, now,
                                                               s.status, False)
        old_seq = self.last_seq
        verdict = self._sequence(s.seq)
        if verdict == "suspect":  # when the old stream's last line and the new first came
            self.cut_t = (before_t, now)
        if verdict == "restart":
            self.restarts += 1
            self.rebooted, self.info_fresh, self.rezero = True, False, False
            applied = any(a.seen and a.want != 0 for a in self.cfg.axes)
            # the datum the offsets were taken in is gone: the box has none (NO_REF), a new
            # power-up's (REFERENCED at once), or it had a ZERO's, which a power cycle forgets
            datum_lost = s.status & (NO_REF | REFERENCED) or self.stream_status & REFERENCED
            if self.zeroed_since_suspect:
                self.log(f"the box restarted (seq {s.seq}) and was zeroed before this line "
                         "confirmed it: the held offsets carry on as base")
            elif applied and datum_lost:
                self.await_zero = True
                self.log(f"the box restarted (seq {s.seq}) without the reference the offsets "
                         "were taken in: holding the last offsets until ZERO")
                if s.status & NO_REF and self.cfg.resume:
                    self.resume_wanted = self._periods_off()
                    self.loaded = False
                    if self.keeper is not None:
                        self.keeper.forget_pending()
                        self.load_extra = self.keeper.extra_periods(old_seq)
            else:
                self.log(f"the box restarted (seq {s.seq}): holding until it has walked back "
                         "from 0 and INFO confirms its model")
        if verdict != "suspect":
            self.stream_status = s.status
        self.fault = bool(s.status & HOLD_BITS)
        if self.rebooted and not s.status & SLEW:
            self.rebooted = False  # the box tracks again: walk to it from the held offset
        reason = self._hold_reason(s.status, verdict)
        if reason:
            # (a restarted box walks from 0 at its slew limit: following it would pull the
            # axis towards 0 and back)
            self.holds += 1
            if reason != self.hold_reason:
                self.log(f"offsets held: {reason}")
            self.hold_reason = reason
            return verdict == "restart"
        if self.hold_reason:
            self.log("offsets follow the box again")
        self.hold_reason = ""
        self._apply(s)
        return False

    def _hold_reason(self, status: int, verdict: str) -> str:
        if self.cfg.model_hash is None:
            return "no expected model hash in the config"
        if self.info is None or not self.info_fresh:
            return "waiting for the box's INFO"
        if self.model_mismatch:
            return (f"the box carries model {self.info.model_hash}"
                    f"{'' if self.info.crc_ok else ' (CRC BAD)'}, expected "
                    f"{self.cfg.model_hash}")
        if verdict == "suspect":
            return f"seq went back to {self.suspect_seq}"
        if status & HOLD_BITS:
            return "box status " + "|".join(protocol.status_names(status & HOLD_BITS))
        if self.rebooted:
            return "the box restarted and walks from 0 (SLEW)"
        if self.await_zero:
            return "the box restarted without its reference: waiting for ZERO"
        return ""

    def _apply(self, s: protocol.Sample) -> None:
        assert self.info is not None
        # the slew limit is per sample period of the box (its INFO), whatever the wall clock
        slew_nm = self.cfg.slew_nm_per_s * self.info.period_ms / 1000.0
        max_abs_nm = self.cfg.max_abs_um * 1000.0
        self.walking = False
        datum, self.rezero = self.rezero, False
        for a in self.cfg.axes:
            if a.index is None or a.index >= len(s.corrections_nm):
                continue
            a.box_nm = s.corrections_nm[a.index]
            bound = math.floor(max_abs_nm / a.nm_per_count + 1e-9)
            target = a.base + round(a.sign * a.box_nm / a.nm_per_count)
            target = max(-bound, min(bound, target))
            if datum:
                # after ZERO the value changes datum (to ~0) at once: the operator touches off
                # once the offset is 0 (LinuxCNC ramps it at OFFSET_AV_RATIO), docs/linuxcnc.md
                a.want = target
            else:
                assert a.step_nm is not None  # load_config: a hash comes with step limits
                step = max(1, math.floor(min(a.step_nm, slew_nm) / a.nm_per_count + 1e-9))
                a.want = max(-bound, min(bound, a.want + max(-step, min(step, target - a.want))))
            a.seen = True
            if a.want != target:
                self.walking = True

    def zero_sent(self) -> None:
        """ZERO went to the box: its ``$OK,ZERO`` is expected."""
        self.zero_pending = True

    def zeroed(self, seq: int) -> None:
        """The box acknowledged ZERO (``$OK,ZERO,<seq>``).

        After a restart without the reference (or while the box says NO_REF) the offsets held
        become each axis's base and the box's change since then is added to them: the tool
        does not move and the drift keeps being corrected. Otherwise the next value is a new
        datum (base 0), applied at once."""
        if not self.zero_pending:
            self.log(f"$OK,ZERO,{seq} without a ZERO sent: ignored (no datum change)")
            return
        self.zero_pending = False
        self.zero_acks += 1
        self.zero_seq = seq
        if self.await_zero or self.status & NO_REF:
            for a in self.cfg.axes:
                a.base = a.want
            # the operator zeroed right after the box came back, before its second line
            # confirmed the restart: that ZERO is the one the restart needs
            self.zeroed_since_suspect = self.suspect_seq is not None
            self.await_zero, self.rezero = False, False
            self.log(f"box zeroed at seq {seq}: the held offsets ("
                     + ", ".join(f"{a.letter.upper()} {a.want}" for a in self.cfg.axes)
                     + " counts) carry on as base; the box's change since then is added")
        else:
            for a in self.cfg.axes:
                a.base = 0
            self.rezero = True
            self.log(f"box zeroed at seq {seq}: the next value is the new datum")

    def _periods_off(self) -> int:
        """Sample periods the box was off: between the old stream's last line and the new
        power-up's first, less the one period between two lines (the box adds the samples it
        has taken since its power-up itself)."""
        period = self.period_s()
        before, first = self.cut_t
        if period is None or period <= 0 or before is None:
            return 0
        return max(0, min(protocol.RESUME_MAX, round((first - before) / period) - 1))

    @property
    def restoring(self) -> bool:
        """After a power cut: the box's kept state is being given back (LOAD) or RESUME is
        outstanding; awaiting-zero is only settled once this is over."""
        loading = self.keeper is not None and (self.keeper.load_pending or
                                               bool(self.keeper.to_load))
        return self.resume_wanted is not None or self.resume_pending or loading

    def resumed(self, seq: int) -> None:
        """``$OK,RESUME,<seq>``: the box continues the state it had before the power cut
        (its retained memory on a battery): its reference, so the offsets held are the ones
        it goes on from; the next lines continue its old sequence."""
        if not self.resume_pending:
            self.log(f"$OK,RESUME,{seq} without a RESUME sent: ignored")
            return
        self.resume_pending = False
        self.await_zero, self.rebooted = False, False
        # the next line continues the old sequence after this one (the samples the box was
        # off for are behind this seq: they are not lines lost on the wire)
        self.last_seq, self.prev_seq, self.suspect_seq, self.last_lost = seq, None, None, 0
        self.log(f"box resumed at seq {seq}: it continues its reference; the offsets follow it "
                 "again, within the step limits")

    def refused(self, reason: str) -> None:
        """``$E,<reason>`` from the box."""
        if reason == "NO_STATE" and self.resume_pending:
            self.resume_pending = False
            self.log("the box kept no state through the power cut (NO_STATE): holding the "
                     "last offsets until ZERO")
        elif reason == "HOLDING" and self.zero_pending:
            self.zero_pending, self.zero_deferred = False, True
            self.log("the box refused ZERO while an axis holds (HOLDING): deferred, sent again "
                     "on the first line without a hold bit (zero-deferred; touch off only "
                     "once zero-acks has counted it)")
        else:
            self.log(f"box refused a command: {reason}")

    # ---- probing in service (MEAS, issue 42) ---------------------------------------------
    def probe_axis(self) -> AxisMap | None:
        return next((a for a in self.cfg.axes if a.letter == self.cfg.probe_axis), None)

    def reading_nm(self, a: AxisMap, delta_mm: float, applied_counts: int) -> float:
        """The axis's displacement since the reference as the probe saw it (nm, the box's
        sign): ``delta_mm`` is the probed position's change since the reference touch
        (machine units), ``applied_counts`` the external offset LinuxCNC applied at the touch.

        The tool tip is at joint + d (d: the thermal displacement along the machine axis) and
        touches the artifact when that reaches the surface. LinuxCNC 2.9's probed position
        (#5061-#5063) is where the joint was, external offset included (measured:
        docs/linuxcnc.md, "Probing in service"), so its change is -(change of d) whatever
        offset is applied, and the box's displacement (offset = sign x correction cancels d,
        so correction = -sign x d) is sign x delta. A control whose probed position leaves
        the offset out (``[probe] probed_includes_offset = no``) measured delta - e: the
        offset is added back."""
        delta_nm = delta_mm * self.cfg.units_mm * 1e6
        if not self.cfg.probed_includes_offset:
            delta_nm += applied_counts * a.nm_per_count
        return a.sign * delta_nm

    def meas_request(self, delta_mm: float, applied_counts: int, now: float) -> bytes | None:
        """A probe reading to send: the MEAS line, or None when the component refuses it
        itself (then ``meas_done`` with the reason: NO_PROBE, LINK, RANGE)."""
        self.meas_done, self.meas_applied, self.meas_reason = False, False, ""
        a = self.probe_axis()
        if a is None:
            return self._meas_local("NO_PROBE", "no [probe] axis in the config")
        if self.meas_pending is not None:
            self.log(f"MEAS: a new request while seq {self.meas_pending['seq']}'s is "
                     "unanswered: the old one is dropped")
            self.meas_pending = None
        if self.info is None or not self.info_fresh or self.model_mismatch or a.index is None \
                or self.last_seq is None:
            return self._meas_local("LINK", "the box's INFO and a sample line are needed first")
        nm = self.reading_nm(a, delta_mm, applied_counts)
        if not (math.isfinite(nm) and protocol.MEAS_NM_MIN <= round(nm) <= protocol.MEAS_NM_MAX):
            return self._meas_local("RANGE", f"reading {nm:g} nm does not fit the protocol")
        nm = round(nm)
        self.meas_pending = {"axis": a.index, "letter": a.letter, "nm": nm,
                             "seq": self.last_seq, "t": now}
        self.meas_nm, self.meas_seq = nm, self.last_seq
        self.log(f"MEAS {a.letter.upper()}: probed {delta_mm:+.6f} mm since the reference "
                 f"(offset applied: {applied_counts} counts) -> {nm} nm at seq {self.last_seq}")
        return protocol.encode_meas(a.index, nm, self.last_seq)

    def _meas_local(self, reason: str, why: str) -> None:
        self.log(f"MEAS refused by the component: {reason} ({why})")
        self._meas_answer(False, reason)
        return None

    def _meas_answer(self, applied: bool, reason: str) -> None:
        self.meas_pending = None
        self.meas_done, self.meas_applied, self.meas_reason = True, applied, reason
        self.meas_count += 1
        if applied:
            self.meas_refused_in_row = 0
        else:
            self.meas_refusals += 1
            self.meas_refused_in_row += 1

    def take_meas_reply(self, m: protocol.MeasReply) -> None:
        """``$M``: the box's answer to the reading in flight."""
        p = self.meas_pending
        if p is None or m.axis != p["axis"] or m.seq != p["seq"]:
            self.log(f"$M for axis {m.axis} seq {m.seq} without that MEAS in flight: ignored")
            return
        a = next(x for x in self.cfg.axes if x.letter == p["letter"])
        if m.innovation_nm is not None:
            a.innovation_nm = m.innovation_nm
        if m.bias_nm is not None:
            a.bias_nm = m.bias_nm
        if m.p_nm2 is not None:
            a.p_nm2 = m.p_nm2
        self._meas_answer(m.applied, m.reason or "")
        self.log(f"MEAS {a.letter.upper()} seq {m.seq}: "
                 + ("applied" if m.applied else f"refused ({m.reason})")
                 + f", innovation {_show_nm(m.innovation_nm)}, bias {_show_nm(m.bias_nm)}"
                 + (f", {self.meas_refused_in_row} refused in a row"
                    if self.meas_refused_in_row > 1 else ""))

    def meas_error(self, reason: str) -> bool:
        """``$E`` while a MEAS is in flight and no ZERO: the box's parser refused it."""
        if self.meas_pending is None or self.zero_pending:
            return False
        self._meas_answer(False, "BAD_ARG" if reason == "BAD_ARG" else reason)
        self.log(f"MEAS refused by the box's parser: $E,{reason}")
        return True

    def check_meas_timeout(self, now: float) -> None:
        p = self.meas_pending
        if p is not None and now - p["t"] > self.cfg.probe_timeout_s:
            self.log(f"MEAS seq {p['seq']}: no answer within {self.cfg.probe_timeout_s:g} s")
            self._meas_answer(False, "TIMEOUT")

    def zero_wait_reason(self) -> str:
        """Why a ZERO now would take a datum that is not a healthy box's ("" : none): the
        box holds or walks an axis (it refuses then), the stream is stale, or the offsets
        still walk to the box's value after a hold (that gap would stay in the datum).
        NO_REF does not wait: a ZERO is what it asks for."""
        if self.stale:
            return "the stream is stale"
        if self.status & NO_REF:  # every axis holds for want of a datum: ZERO is the cure
            return ""
        held = self.status & (HOLD_BITS | SLEW)
        if held:
            return "box status " + "|".join(protocol.status_names(held))
        if self.walking:
            return "the offsets still walk to the box's value"
        return ""

    def deferred_zero_due(self) -> bool:
        """A deferred ZERO can go now (nothing to wait for, none in flight)."""
        return self.zero_deferred and not self.zero_pending and not self.zero_wait_reason()

    def bad_line(self, raw: bytes, err: Exception | str) -> None:
        self.bad_lines += 1
        self.holds += 1 if raw.startswith(b"$C,") or raw is OVERLONG else 0
        if self.bad_lines <= 10 or self.bad_lines % 100 == 0:
            self.log(f"bad line #{self.bad_lines} (offsets held): {err}")

    def check_stale(self, now: float) -> None:
        period = self.period_s()
        if period is None or self.last_line_t is None:
            return
        stale = now - self.last_line_t > self.cfg.stale_periods * period
        if stale and not self.stale:
            self.log(f"no sample line for {now - self.last_line_t:.3g} s "
                     f"({self.cfg.stale_periods:g} periods): stale, offsets held")
        self.stale = stale

    def age_s(self, now: float) -> float:
        return now - self.last_line_t if self.last_line_t is not None else -1.0


class HalDriver:
    """The HAL side: pins, the LinuxCNC counts bookkeeping, machine-off resync."""

    def __init__(self, cfg: Config, comp: Compensator, name: str = NAME) -> None:
        import hal

        self.hal, self.cfg, self.comp = hal, cfg, comp
        h = self.h = hal.component(name)
        for pin, kind, direction in (
                ("enable", hal.HAL_BIT, hal.HAL_IN), ("machine-on", hal.HAL_BIT, hal.HAL_IN),
                ("homed", hal.HAL_BIT, hal.HAL_IN), ("zero", hal.HAL_BIT, hal.HAL_IN),
                ("connected", hal.HAL_BIT, hal.HAL_OUT), ("active", hal.HAL_BIT, hal.HAL_OUT),
                ("fault", hal.HAL_BIT, hal.HAL_OUT), ("holding", hal.HAL_BIT, hal.HAL_OUT),
                ("walking", hal.HAL_BIT, hal.HAL_OUT), ("stale", hal.HAL_BIT, hal.HAL_OUT),
                ("extrapolating", hal.HAL_BIT, hal.HAL_OUT),
                ("referenced", hal.HAL_BIT, hal.HAL_OUT), ("age-s", hal.HAL_FLOAT, hal.HAL_OUT),
                ("status", hal.HAL_S32, hal.HAL_OUT), ("seq", hal.HAL_S32, hal.HAL_OUT),
                ("bad-lines", hal.HAL_S32, hal.HAL_OUT), ("lost-lines", hal.HAL_S32, hal.HAL_OUT),
                ("holds", hal.HAL_S32, hal.HAL_OUT), ("restarts", hal.HAL_S32, hal.HAL_OUT),
                ("zero-acks", hal.HAL_S32, hal.HAL_OUT), ("zero-seq", hal.HAL_S32, hal.HAL_OUT),
                ("model-mismatch", hal.HAL_BIT, hal.HAL_OUT),
                ("awaiting-zero", hal.HAL_BIT, hal.HAL_OUT),
                ("zero-deferred", hal.HAL_BIT, hal.HAL_OUT),
                ("restoring", hal.HAL_BIT, hal.HAL_OUT),
                # probing in service (MEAS): docs/linuxcnc.md "Probing in service"
                ("meas-mm", hal.HAL_FLOAT, hal.HAL_IN), ("meas-request", hal.HAL_BIT, hal.HAL_IN),
                ("meas-done", hal.HAL_BIT, hal.HAL_OUT), ("meas-applied", hal.HAL_BIT, hal.HAL_OUT),
                ("meas-refused", hal.HAL_BIT, hal.HAL_OUT),
                ("meas-reason", hal.HAL_S32, hal.HAL_OUT),
                ("meas-nm", hal.HAL_S32, hal.HAL_OUT), ("meas-seq", hal.HAL_S32, hal.HAL_OUT),
                ("meas-count", hal.HAL_S32, hal.HAL_OUT),
                ("meas-refusals", hal.HAL_S32, hal.HAL_OUT),
                ("meas-refused-in-row", hal.HAL_S32, hal.HAL_OUT)):
            h.newpin(pin, kind, direction)
        for a in cfg.axes:
            p = a.letter
            h.newpin(f"{p}.counts", hal.HAL_S32, hal.HAL_OUT)
            h.newpin(f"{p}.scale", hal.HAL_FLOAT, hal.HAL_OUT)
            h.newpin(f"{p}.eoffset-enable", hal.HAL_BIT, hal.HAL_OUT)
            h.newpin(f"{p}.clear", hal.HAL_BIT, hal.HAL_OUT)
            h.newpin(f"{p}.request", hal.HAL_FLOAT, hal.HAL_IN)
            h.newpin(f"{p}.offset", hal.HAL_FLOAT, hal.HAL_OUT)
            h.newpin(f"{p}.correction-nm", hal.HAL_S32, hal.HAL_OUT)
            h.newpin(f"{p}.bias-nm", hal.HAL_S32, hal.HAL_OUT)
            h.newpin(f"{p}.innovation-nm", hal.HAL_S32, hal.HAL_OUT)
            h.newpin(f"{p}.p-nm2", hal.HAL_S32, hal.HAL_OUT)
            h[f"{p}.scale"] = self.scale(a)
            h[f"{p}.eoffset-enable"] = True
        h["seq"], h["zero-seq"], h["age-s"], h["meas-seq"] = -1, -1, -1.0, -1
        self.meas_was = False
        self.live_since: float | None = None
        self.last_write = 0.0
        self.need_sync = True
        self.zero_was = False
        h.ready()

    def scale(self, a: AxisMap) -> float:
        """eoffset-scale: machine units per count."""
        return a.nm_per_count * 1e-6 / self.cfg.units_mm

    def update(self, now: float, port: Port) -> None:
        h, comp = self.h, self.comp
        live = bool(h["machine-on"]) and bool(h["homed"])
        enabled = bool(h["enable"])
        if not live or not enabled:
            # Machine off: LinuxCNC ignores counts and drops the offset at the next machine-on.
            # Disabled: eoffset-clear ramps it to 0. Either way: resync when it comes back.
            self.live_since, self.need_sync = None, True
        elif self.live_since is None:
            self.live_since = now
        for a in self.cfg.axes:
            h[f"{a.letter}.clear"] = live and not enabled
        if self.live_since is not None and now - self.live_since >= self.cfg.settle_s:
            for a in self.cfg.axes:
                request = round(h[f"{a.letter}.request"] / self.scale(a))
                if self.need_sync:
                    # counts are taken as a change: make request equal what we want
                    h[f"{a.letter}.counts"] = _s32(h[f"{a.letter}.counts"] + a.want - request)
                    a.sent = a.want
                elif a.want != a.sent:
                    h[f"{a.letter}.counts"] = _s32(h[f"{a.letter}.counts"] + a.want - a.sent)
                    a.sent = a.want
                    self.last_write = now
                elif now - self.last_write > self.cfg.settle_s and request != a.sent:
                    # LinuxCNC lost a change (it ignores counts in some states): put it back
                    comp.log(f"axis {a.letter.upper()}: eoffset-request is {request} counts, "
                             f"expected {a.sent}: resynchronising")
                    h[f"{a.letter}.counts"] = _s32(h[f"{a.letter}.counts"] + a.sent - request)
                    self.last_write = now
            if self.need_sync:
                self.last_write, self.need_sync = now, False
        zero = bool(h["zero"])
        if zero and not self.zero_was:
            wait = comp.zero_wait_reason()
            if wait:
                comp.zero_deferred = True
                comp.log(f"zero: deferred ({wait}); sent once that is over")
            elif port.write(b"ZERO\r\n"):
                comp.zero_sent()
                comp.log("zero: sending ZERO")
            else:
                comp.log("zero: box not connected, ZERO not sent")
        self.zero_was = zero
        self.probe(now, port)
        comp.check_stale(now)
        status = comp.status
        h["connected"] = port.fd is not None and comp.info is not None and comp.info_fresh
        h["active"] = self.live_since is not None and not self.need_sync and enabled
        h["fault"] = comp.fault or comp.model_mismatch
        h["model-mismatch"] = comp.model_mismatch
        h["awaiting-zero"] = comp.await_zero
        h["zero-deferred"] = comp.zero_deferred
        h["restoring"] = comp.restoring
        h["stale"] = comp.stale
        h["holding"] = comp.holding
        h["walking"] = comp.walking
        h["extrapolating"] = bool(status & EXTRAP)
        h["referenced"] = bool(status & REFERENCED)
        h["status"] = status
        h["age-s"] = comp.age_s(now)
        h["seq"] = _s32(comp.last_seq if comp.last_seq is not None else -1)
        h["bad-lines"], h["lost-lines"] = comp.bad_lines, comp.lost_lines
        h["holds"], h["restarts"] = comp.holds, comp.restarts
        h["zero-acks"], h["zero-seq"] = comp.zero_acks, _s32(comp.zero_seq)
        for a in self.cfg.axes:
            h[f"{a.letter}.offset"] = a.want * self.scale(a)
            h[f"{a.letter}.correction-nm"] = a.box_nm
            h[f"{a.letter}.bias-nm"] = _s32(a.bias_nm)
            h[f"{a.letter}.innovation-nm"] = _s32(a.innovation_nm)
            h[f"{a.letter}.p-nm2"] = _s32(min(a.p_nm2, (1 << 31) - 1))

    def probe(self, now: float, port: Port) -> None:
        """``meas-request`` rising: send the reading; ``meas-done`` while the request is up
        and answered (the subroutine waits on it with M66, then drops the request)."""
        h, comp = self.h, self.comp
        request = bool(h["meas-request"])
        if request and not self.meas_was:
            a = comp.probe_axis()
            # the offset LinuxCNC applies: its eoffset-request, in counts
            applied = round(h[f"{a.letter}.request"] / self.scale(a)) if a else 0
            line = comp.meas_request(float(h["meas-mm"]), applied, now)
            if line is not None and not port.write(line):
                comp.meas_pending = None
                comp._meas_local("LINK", "the port is closed")
        self.meas_was = request
        comp.check_meas_timeout(now)
        h["meas-done"] = request and comp.meas_done
        h["meas-applied"] = comp.meas_done and comp.meas_applied
        h["meas-refused"] = comp.meas_done and not comp.meas_applied
        h["meas-reason"] = MEAS_REASON_CODES.get(comp.meas_reason, 0)
        h["meas-nm"] = _s32(comp.meas_nm if comp.meas_nm is not None else 0)
        h["meas-seq"] = _s32(comp.meas_seq if comp.meas_seq is not None else -1)
        h["meas-count"], h["meas-refusals"] = comp.meas_count, comp.meas_refusals
        h["meas-refused-in-row"] = comp.meas_refused_in_row


def _show_nm(value: int | None) -> str:
    return "-" if value is None else f"{value} nm"


def _s32(value: int) -> int:
    value %= 1 << 32
    return value - (1 << 32) if value >= 1 << 31 else value


def handle_line(comp: Compensator, port: Port, raw: bytes, now: float) -> None:
    if not raw:
        return
    if raw is OVERLONG:
        comp.bad_line(raw, f"more than {MAX_LINE_BYTES} bytes without a newline: discarded "
                      "up to the next newline")
        return
    try:
        msg = protocol.decode(raw)
    except protocol.ProtocolError as exc:
        comp.bad_line(raw, exc)
        return
    if isinstance(msg, protocol.Sample):
        if comp.take_sample(msg, now):
            port.write(b"INFO\r\n")  # a restarted box may carry another model
        _resume_step(comp, port)
        keeper = comp.keeper
        if (keeper is not None and msg.status & REFERENCED and not comp.hold_reason
                and comp.resume_wanted is None and not comp.resume_pending):
            line = keeper.ask(msg.seq)  # keep the state this datum lives in (issue 41)
            if line is not None:
                port.write(line)
        if comp.deferred_zero_due() and port.write(b"ZERO\r\n"):
            comp.zero_deferred = False
            comp.zero_sent()
            comp.log(f"zero: the box no longer holds (seq {msg.seq}): sending the deferred ZERO")
    elif isinstance(msg, protocol.Info):
        comp.take_info(msg)
    elif isinstance(msg, protocol.Ack) and msg.command == "ZERO":
        comp.zeroed(msg.value)
    elif isinstance(msg, protocol.Ack) and msg.command == "RESUME":
        comp.resumed(msg.value)
    elif isinstance(msg, protocol.BlockPiece):
        if comp.keeper is not None:
            comp.keeper.take_piece(msg)
    elif isinstance(msg, protocol.Ack) and msg.command == "SNAP":
        why = comp.keeper.snapped(msg.value) if comp.keeper is not None else "no keeper"
        if why:
            comp.log(why)
    elif isinstance(msg, protocol.Ack) and msg.command == "LOAD":
        if comp.keeper is None or not comp.keeper.load_pending:
            comp.log(f"$OK,LOAD,{msg.value} without a LOAD sent: ignored")
            return
        line = comp.keeper.next_load()
        if line is not None:
            port.write(line)
        else:
            _resume_step(comp, port)
    elif isinstance(msg, protocol.MeasReply):
        comp.take_meas_reply(msg)
    elif isinstance(msg, protocol.ErrorReply):
        keeper = comp.keeper
        if comp.meas_error(msg.reason):
            return
        if keeper is not None and keeper.load_refused():
            comp.log(f"the box refused its kept state ({msg.reason}): RESUME without it")
            comp.load_extra = 0
            _resume_step(comp, port)
        elif not comp.resume_pending and keeper is not None and keeper.refused():
            pass  # SNAP before the box had a state to give (NO_STATE): asked again later
        else:
            comp.refused(msg.reason)


def _resume_step(comp: Compensator, port: Port) -> None:
    """After a power cut: give the box its kept state back (LOAD), then RESUME it."""
    keeper = comp.keeper
    if comp.resume_wanted is None or (keeper is not None and keeper.load_pending):
        return
    if keeper is not None and keeper.kept is not None and not comp.loaded:
        comp.loaded = True
        line = keeper.start_load()
        if line is not None and port.write(line):
            comp.log(f"giving the box the state it had at seq {keeper.kept.seq} (LOAD, "
                     f"{len(keeper.kept.block)} bytes), then RESUME")
            return
        keeper.load_refused()
    n, comp.resume_wanted = comp.resume_wanted + (comp.load_extra if comp.loaded else 0), None
    n = min(n, protocol.RESUME_MAX)
    if port.write(protocol.encode_command("RESUME", n)):
        comp.resume_pending = True
        comp.log(f"asked the box to RESUME after {n} sample periods off")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog=NAME, description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", required=True, help="component config file (thermalcomp.conf)")
    ap.add_argument("--name", default=NAME, help="HAL component name (default thermalcomp)")
    args = ap.parse_args(argv)
    try:
        cfg = load_config(args.config)
    except ConfigError as exc:
        print(f"{NAME}: {exc}", file=sys.stderr)
        return 2
    comp = Compensator(cfg)
    driver = HalDriver(cfg, comp, args.name)
    port = Port(cfg.port, cfg.baud)
    stop = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    next_open = next_info = 0.0
    import select

    try:
        while not stop:
            now = time.monotonic()
            if port.fd is None and now >= next_open:
                if port.open():
                    comp.log(f"opened {cfg.port}")
                    next_info = now
                else:
                    next_open = now + 0.5
            if port.fd is not None and comp.needs_info() and now >= next_info:
                port.write(b"INFO\r\n")  # ask rather than wait for a banner (and again)
                next_info = now + 1.0
            if port.fd is not None:
                ready, _, _ = select.select([port.fd], [], [], cfg.poll_s)
                if ready:
                    lines = port.read_lines()
                    if lines is None:
                        comp.log(f"{cfg.port} closed: offsets held, reopening")
                        port.close()
                        comp.info_fresh = False
                        next_open = time.monotonic() + 0.2
                    else:
                        t = time.monotonic()
                        for raw in lines:
                            handle_line(comp, port, raw, t)
            else:
                time.sleep(cfg.poll_s)
            driver.update(time.monotonic(), port)
    except KeyboardInterrupt:
        pass
    finally:
        port.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())

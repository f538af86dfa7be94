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
import signal
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

# the component's parts (stdlib + the stdlib-only contract, like this file); the names the
# HAL side, the fault campaign and the tests use are this module's public face
from thermal_comp.cnc.compconfig import (  # noqa: E402
    DEFAULT_MAX_ABS_UM,
    UNITS_MM,
    AxisMap,
    Config,
    ConfigError,
    axis_step_nm,
    load_config,
)
from thermal_comp.cnc.compensator import (  # noqa: E402
    BEYOND,
    CLAMP,
    EXTRAP,
    HOLD,
    HOLD_BITS,
    IMPLAUSIBLE,
    MEAS_LOCAL_REASONS,
    MEAS_REASON_CODES,
    MODEL_BAD,
    NAME,
    NO_DATA,
    NO_REF,
    REFERENCED,
    SEQ_MOD,
    SLEW,
    Compensator,
)
from thermal_comp.cnc.serialport import MAX_LINE_BYTES, OVERLONG, Port  # noqa: E402
from thermal_comp.contract import protocol  # noqa: E402  (stdlib only: docs/architecture.md)

__all__ = ["BEYOND", "CLAMP", "DEFAULT_MAX_ABS_UM", "EXTRAP", "HOLD", "HOLD_BITS", "IMPLAUSIBLE",
           "MAX_LINE_BYTES", "MEAS_LOCAL_REASONS", "MEAS_REASON_CODES", "MODEL_BAD", "NAME",
           "NO_DATA", "NO_REF", "OVERLONG", "REFERENCED", "SEQ_MOD", "SLEW", "UNITS_MM",
           "AxisMap", "Compensator", "Config", "ConfigError", "HalDriver", "Port",
           "axis_step_nm", "handle_line", "load_config", "main"]


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
        """One poll: the offsets to LinuxCNC, the operator's zero, the probe, the pins."""
        self.offsets(now)
        self.zero(port)
        self.probe(now, port)
        self.comp.check_stale(now)
        self.show(now, port)

    def offsets(self, now: float) -> None:
        """Counts for what the component wants, with the machine-off and enable resync."""
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

    def zero(self, port: Port) -> None:
        """``zero`` rising: ZERO to the box, or deferred while it cannot take a datum."""
        h, comp = self.h, self.comp
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

    def show(self, now: float, port: Port) -> None:
        """The status pins."""
        h, comp, status = self.h, self.comp, self.comp.status
        h["connected"] = port.fd is not None and comp.info is not None and comp.info_fresh
        h["active"] = self.live_since is not None and not self.need_sync and bool(h["enable"])
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


def _s32(value: int) -> int:
    value %= 1 << 32
    return value - (1 << 32) if value >= 1 << 31 else value


def handle_line(comp: Compensator, port: Port, raw: bytes, now: float) -> None:
    """One line from the box, in the order it came: to the compensator, and what the
    component answers on the wire (INFO after a restart, SNAP / LOAD / RESUME, a ZERO)."""
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
        _sample(comp, port, msg, now)
    elif isinstance(msg, protocol.Info):
        comp.take_info(msg)
    elif isinstance(msg, protocol.Ack) and msg.command == "ZERO":
        comp.zeroed(msg.value)
    elif isinstance(msg, protocol.Ack) and msg.command == "RESUME":
        comp.resumed(msg.value)
    elif isinstance(msg, protocol.BlockPiece | protocol.Ack) and comp.keeper is not None:
        _kept_state(comp, port, msg)
    elif isinstance(msg, protocol.MeasReply):
        comp.take_meas_reply(msg)
    elif isinstance(msg, protocol.ErrorReply):
        _refused(comp, port, msg.reason)


def _sample(comp: Compensator, port: Port, msg: protocol.Sample, now: float) -> None:
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


def _kept_state(comp: Compensator, port: Port,
                msg: protocol.BlockPiece | protocol.Ack) -> None:
    """The box's state block coming in (SNAP) or going back (LOAD)."""
    keeper = comp.keeper
    assert keeper is not None
    if isinstance(msg, protocol.BlockPiece):
        keeper.take_piece(msg)
    elif msg.command == "SNAP":
        why = keeper.snapped(msg.value)
        if why:
            comp.log(why)
    elif msg.command == "LOAD":
        if not keeper.load_pending:
            comp.log(f"$OK,LOAD,{msg.value} without a LOAD sent: ignored")
            return
        line = keeper.next_load()
        if line is not None:
            port.write(line)
        else:
            _resume_step(comp, port)


def _refused(comp: Compensator, port: Port, reason: str) -> None:
    """``$E,<reason>``: the answer to the command outstanding (MEAS, LOAD, RESUME, SNAP, ZERO)."""
    keeper = comp.keeper
    if comp.meas_error(reason):
        return
    if keeper is not None and keeper.load_refused():
        comp.log(f"the box refused its kept state ({reason}): RESUME without it")
        comp.load_extra = 0
        _resume_step(comp, port)
    elif not comp.resume_pending and keeper is not None and keeper.refused():
        pass  # SNAP before the box had a state to give (NO_STATE): asked again later
    else:
        comp.refused(reason)


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

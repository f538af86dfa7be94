"""The thermalcomp component's logic, without HAL: what the offsets and pins should be after
each line, command reply and tick (the rules are in cnc/thermalcomp.py's docstring and
docs/linuxcnc.md). Standard library and the stdlib-only contract only.
"""

from __future__ import annotations

import math
import sys

from thermal_comp.cnc.compconfig import AxisMap, Config
from thermal_comp.cnc.keptstate import StateKeeper
from thermal_comp.cnc.serialport import OVERLONG
from thermal_comp.contract import protocol

NAME = "thermalcomp"
_S = protocol.Status  # the status bits have one home: contract/protocol.py
MODEL_BAD, HOLD, SLEW, CLAMP = int(_S.MODEL_BAD), int(_S.HOLD), int(_S.SLEW), int(_S.CLAMP)
NO_DATA, EXTRAP, REFERENCED = int(_S.NO_DATA), int(_S.EXTRAP), int(_S.REFERENCED)
IMPLAUSIBLE, NO_REF, BEYOND = int(_S.IMPLAUSIBLE), int(_S.NO_REF), int(_S.BEYOND)
# the box says: do not trust this sample. CLAMP: the box's value is not the model's.
HOLD_BITS = MODEL_BAD | HOLD | CLAMP | NO_DATA | IMPLAUSIBLE | NO_REF | BEYOND
SEQ_MOD = 1 << 32
# meas-reason: 0 applied (or nothing yet); 1.. the box's refusals (contract.protocol.MEAS_REASONS,
# in that order); then the component's own: the request never reached the box, or no answer.
MEAS_LOCAL_REASONS = ("NO_PROBE", "LINK", "RANGE", "TIMEOUT", "BAD_ARG")
MEAS_REASON_CODES = {r: i + 1 for i, r in enumerate(protocol.MEAS_REASONS
                                                   + MEAS_LOCAL_REASONS)}


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
                 + (f"applied{f' ({m.reason})' * bool(m.reason)}" if m.applied  # REOPEN
                    else f"refused ({m.reason})")
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


def _show_nm(value: int | None) -> str:
    return "-" if value is None else f"{value} nm"

"""Judge a captured replay against the host's expectation.

Over 400 lines: the line-by-line comparison and the replay judgement share one report.

Four checks: 1. every correction equals the integer twin's (after the documented
output stage), bit for bit, and so do the status word and the echoed temperature codes;
2. the float model (contract/terms.py on the quantised temperatures) is within the bound codegen
proved, wherever the box outputs the model value directly; 3. no sample line is lost,
duplicated or reordered (``seq``); 4. the residual measured − correction beside the raw
displacement, per axis, RMS and peak. The lines are decoded with contract/protocol.py only.

And the judgement (``Judging``): a box that matches its twin can still be useless
or alarming: it fails when it held (HOLD/NO_DATA) or limited (SLEW) more than a stated share
of the samples, or never corrected at all (a model trained in Kelvin: every reading out of
range, every sample held); and (issue 41, "never worse than no compensation") when an axis's
compensated error is larger than its raw error (RMS or peak), when the clamp (CLAMP) engaged on
more than a stated share of the samples, or when the output stepped by more than the axis's
step limit between two consecutive lines of a power-up.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from thermal_comp.contract.protocol import ErrorReply, Info, ProtocolError, Sample, decode
from thermal_comp.contract.terms import Term
from thermal_comp.hil.expect import (
    CLAMP,
    HOLD,
    MODEL_BAD,
    NO_DATA,
    SLEW,
    STATUS_NAMES,
    Expected,
    status_text,
)
from thermal_comp.hil.feed import Feed
from thermal_comp.hil.runner import Capture, Session
from thermal_comp.host.fitting import design_matrix

MAX_PROBLEMS = 20  # detail lines kept in a report; counts are always complete


@dataclass(frozen=True)
class Judging:
    """How much holding and limiting a replay may show before it fails.

    The defaults: a box that holds (a faulted input, HOLD/NO_DATA) or limits its output step
    (SLEW: walking back or the per-axis limit) on more than 10 % of the samples of a run is
    not compensating that run, whatever its twin says; one that never corrects fails always.
    """

    max_held_fraction: float = 0.10
    max_limited_fraction: float = 0.10
    require_correction: bool = True
    # The clamp (BOX_MAX_CORRECTION_NM, 200 um) is the box's last resort: a sound model stays
    # far inside it. 1 % lets a short excursion be clamped (the output stays bounded, which is
    # the clamp's job) but not a model that lives at the bound (x50 coefficients: 99 %).
    max_clamped_fraction: float = 0.01
    # Compensation must not leave a larger error than no compensation (RMS or peak, per axis
    # with a measured displacement), and no output step may exceed the axis's step limit.
    require_no_worse: bool = True
    require_step_limit: bool = True


@dataclass
class AxisReport:
    name: str
    mismatches: int = 0
    max_abs_diff_nm: int = 0
    raw_rms_um: float | None = None
    raw_peak_um: float | None = None
    compensated_rms_um: float | None = None
    compensated_peak_um: float | None = None
    float_max_diff_um: float | None = None
    float_samples: int = 0
    bound_um: float | None = None
    max_step_nm: int | None = None  # the axis's step limit (header), None when unknown
    largest_step_nm: int | None = None  # largest output step between consecutive lines
    steps_over_limit: int = 0  # consecutive-line steps beyond max_step_nm
    first_step_over: int | None = None  # sample of the first of them

    def to_json(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k != "name"}

    def worse_than_raw(self) -> list[str]:
        """Which of RMS and peak the compensation made worse than the raw drift."""
        out = []
        if self.raw_rms_um is not None and self.compensated_rms_um is not None \
                and self.compensated_rms_um > self.raw_rms_um:
            out.append(f"RMS {self.compensated_rms_um:.3f} > raw {self.raw_rms_um:.3f}")
        if self.raw_peak_um is not None and self.compensated_peak_um is not None \
                and self.compensated_peak_um > self.raw_peak_um:
            out.append(f"peak {self.compensated_peak_um:.3f} > raw {self.raw_peak_um:.3f}")
        return out


@dataclass
class SessionLines:
    """A session's lines, decoded and sorted by kind."""

    samples: list[Sample] = field(default_factory=list)
    info: list[Info] = field(default_factory=list)
    errors: list[ErrorReply] = field(default_factory=list)
    other: list[object] = field(default_factory=list)
    bad: list[str] = field(default_factory=list)


@dataclass
class ReplayReport:
    samples: int
    received: int = 0
    mismatches: int = 0  # samples where a correction differs from the expectation
    status_mismatches: int = 0
    code_mismatches: int = 0
    max_abs_diff_nm: int = 0
    lost: int = 0
    duplicated: int = 0
    reordered: int = 0
    bad_lines: int = 0
    sessions: int = 1
    axes: dict[str, AxisReport] = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)  # $E reasons received, in order
    fw_out_nm: np.ndarray | None = None  # (n, axes) what the box sent; missing rows = 0
    fw_status: np.ndarray | None = None  # (n,) status words; -1 where no line arrived
    fw_seq: np.ndarray | None = None  # (n,) seq of the line of each sample; -1 where none
    fw_session: np.ndarray | None = None  # (n,) session (power-up) of each sample's line
    judging: Judging | None = None
    elapsed_s: float | None = None
    problems_fatal: bool = False  # the replay itself broke (timeout, crash)
    extra_checks: dict[str, bool] = field(default_factory=dict)  # e.g. qemu_equals_native

    # MEAS (issue 42): per axis static / updated RMS, readings applied and refused
    service: dict[str, dict] = field(default_factory=dict)

    @property
    def float_ok(self) -> bool:
        return all(a.float_max_diff_um is None or a.bound_um is None
                   or a.float_max_diff_um <= a.bound_um + 1e-9 for a in self.axes.values())

    def _share(self, bits: int) -> float:
        """Share of the received samples whose status carries any of ``bits``."""
        if self.fw_status is None:
            return 0.0
        got = self.fw_status[self.fw_status >= 0]
        return float(np.mean((got & bits) != 0)) if got.size else 0.0

    @property
    def held_fraction(self) -> float:
        return self._share(HOLD | NO_DATA)

    @property
    def limited_fraction(self) -> float:
        return self._share(SLEW)

    @property
    def clamped_fraction(self) -> float:
        return self._share(CLAMP)

    @property
    def worse_axes(self) -> dict[str, list[str]]:
        """Axes whose compensated error exceeds the raw one, with what exceeds."""
        return {name: w for name, a in self.axes.items() if (w := a.worse_than_raw())}

    @property
    def step_axes(self) -> dict[str, AxisReport]:
        """Axes whose output stepped beyond their step limit between consecutive lines."""
        return {name: a for name, a in self.axes.items() if a.steps_over_limit}

    @property
    def corrected_samples(self) -> int:
        """Received samples on which every axis had its correction (no HOLD, NO_DATA or
        MODEL_BAD)."""
        if self.fw_status is None:
            return 0
        got = self.fw_status[self.fw_status >= 0]
        return int(np.count_nonzero((got & (HOLD | NO_DATA | MODEL_BAD)) == 0))

    @property
    def judgement(self) -> dict[str, bool]:
        j = self.judging
        if j is None:
            return {}
        out = {"held_within_limit": self.held_fraction <= j.max_held_fraction,
               "limited_within_limit": self.limited_fraction <= j.max_limited_fraction,
               "clamped_within_limit": self.clamped_fraction <= j.max_clamped_fraction}
        if j.require_correction:
            out["corrected"] = self.corrected_samples > 0
        if j.require_no_worse:
            out["no_worse_than_uncompensated"] = not self.worse_axes
        if j.require_step_limit:
            out["steps_within_limit"] = not self.step_axes
        return out

    @property
    def checks(self) -> dict[str, bool]:
        return {
            "twin_bit_exact": self.mismatches == 0 and self.status_mismatches == 0
            and self.code_mismatches == 0,
            "float_within_bound": self.float_ok,
            "no_lost_duplicated_reordered": self.lost == 0 and self.duplicated == 0
            and self.reordered == 0 and self.bad_lines == 0,
            **self.judgement,
            **self.extra_checks,
        }

    def judgement_reasons(self) -> list[str]:
        """Why the judgement failed, in words (empty when it passed)."""
        j, out = self.judging, []
        if j is None:
            return out
        counts = self.status_counts
        faults = ", ".join(f"{k} on {v}" for k, v in sorted(counts.items(), key=lambda kv: -kv[1])
                           if k in ("RANGE", "OPEN", "TC_FAULT", "AUX_FAULT", "IMPLAUSIBLE",
                                    "MODEL_BAD"))
        received = int((self.fw_status >= 0).sum()) if self.fw_status is not None else 0
        if j.require_correction and received and self.corrected_samples == 0:
            out.append(f"the box never corrected: all {received} samples held"
                       + (f" ({faults})" if faults else "")
                       + "; readings outside their channels' valid range on every sample "
                       "point at a model trained in other units (Kelvin?) or a wiring fault")
        if self.held_fraction > j.max_held_fraction:
            out.append(f"the box held on {100 * self.held_fraction:.1f} % of the samples "
                       f"(HOLD/NO_DATA; limit {100 * j.max_held_fraction:g} %, "
                       f"--max-held-fraction)" + (f": {faults}" if faults else ""))
        if self.limited_fraction > j.max_limited_fraction:
            out.append(f"the box limited its output step on {100 * self.limited_fraction:.1f} % "
                       f"of the samples (SLEW; limit {100 * j.max_limited_fraction:g} %, "
                       "--max-limited-fraction): the model output changes faster than its "
                       "step limit")
        if self.clamped_fraction > j.max_clamped_fraction:
            out.append(f"the box clamped its output on {100 * self.clamped_fraction:.1f} % of "
                       f"the samples (CLAMP; limit {100 * j.max_clamped_fraction:g} %, "
                       "--max-clamped-fraction): the model asks for more than the box's "
                       "maximum correction; its coefficients or units are wrong")
        if j.require_no_worse:
            for name, what in self.worse_axes.items():
                out.append(f"axis {name}: the compensated error is worse than no compensation "
                           f"({', '.join(what)} um): the box makes this axis less accurate")
        if j.require_step_limit:
            for name, a in self.step_axes.items():
                out.append(f"axis {name}: the output stepped by up to {a.largest_step_nm} nm "
                           f"between consecutive samples, beyond its step limit "
                           f"{a.max_step_nm} nm ({a.steps_over_limit} times, first at sample "
                           f"{a.first_step_over}; a ZERO's change of datum not counted)")
        return out

    @property
    def status_counts(self) -> dict[str, int]:
        """Samples whose status word (as the box sent it) carries each bit."""
        if self.fw_status is None:
            return {}
        got = self.fw_status[self.fw_status >= 0]
        return {name: int(((got >> i) & 1).sum()) for i, name in enumerate(STATUS_NAMES)
                if ((got >> i) & 1).any()}

    @property
    def ok(self) -> bool:
        return all(self.checks.values()) and not self.problems_fatal

    def note(self, text: str) -> None:
        if len(self.problems) < MAX_PROBLEMS:
            self.problems.append(text)

    def to_json(self) -> dict:
        out = {
            "samples": self.samples,
            "mismatches": self.mismatches,
            **({"service": self.service} if self.service else {}),
            "max_abs_diff_nm": self.max_abs_diff_nm,
            "axes": {name: a.to_json() for name, a in self.axes.items()},
            "ok": self.ok,
            "checks": self.checks,
            "received": self.received,
            "status_mismatches": self.status_mismatches,
            "status_counts": self.status_counts,
            "held_fraction": round(self.held_fraction, 6),
            "limited_fraction": round(self.limited_fraction, 6),
            "clamped_fraction": round(self.clamped_fraction, 6),
            "corrected_samples": self.corrected_samples,
            "judging": None if self.judging is None else dict(self.judging.__dict__),
            "judgement_problems": self.judgement_reasons(),
            "code_mismatches": self.code_mismatches,
            "lost": self.lost,
            "duplicated": self.duplicated,
            "reordered": self.reordered,
            "bad_lines": self.bad_lines,
            "sessions": self.sessions,
            "problems": self.problems,
        }
        if self.elapsed_s is not None:
            out["elapsed_s"] = round(self.elapsed_s, 3)
            out["samples_per_s"] = round(self.samples / self.elapsed_s, 1) if self.elapsed_s \
                else None
        return out


def decode_session(session: Session) -> SessionLines:
    res = SessionLines()
    for raw in session.lines:
        if not raw:
            continue
        try:
            msg = decode(raw)
        except ProtocolError as exc:
            res.bad.append(str(exc))
            continue
        if isinstance(msg, Sample):
            res.samples.append(msg)
        elif isinstance(msg, Info):
            res.info.append(msg)
        elif isinstance(msg, ErrorReply):
            res.errors.append(msg)
        else:
            res.other.append(msg)
    return res


def sequence_problems(seqs: list[int], n_fed: int) -> tuple[int, int, int]:
    """(lost, duplicated, reordered) for one session fed ``n_fed`` samples with RATE 1."""
    arr = np.asarray(seqs, dtype=np.int64)
    reordered = int(np.count_nonzero(np.diff(arr) < 0)) if arr.size > 1 else 0
    uniq, counts = np.unique(arr, return_counts=True)
    duplicated = int(np.sum(counts - 1))
    lost = n_fed - int(np.count_nonzero((uniq >= 0) & (uniq < n_fed)))
    return lost, duplicated, reordered


def float_predictions(model: dict, feed: Feed, codes: np.ndarray, rows: slice) -> np.ndarray:
    """The float model (contract/terms.py) on the quantised inputs of one session: (n, axes) um."""
    from thermal_comp.hil.feed import aux_names, channel_sensors

    cols: dict[str, np.ndarray] = {}
    for c, name in enumerate(channel_sensors(model)):
        cols[name] = codes[rows, c].astype(float) / 128.0
    for k, name in enumerate(aux_names(model)):
        cols[name] = feed.aux[rows, k].astype(float)
    period = float(model["sample_period_s"])
    out = []
    for axis in feed.axes:
        spec = model["axes"][axis]
        terms = [Term.from_json(t) for t in spec["terms"]]
        coefs = np.array([float(t["coef"]) for t in spec["terms"]])
        x = design_matrix(terms, cols, period) if cols else np.empty((rows.stop - rows.start, 0))
        out.append(float(spec["intercept"]) + x @ coefs)
    return np.column_stack(out) if out else np.empty((rows.stop - rows.start, 0))


@dataclass
class _Received:
    """Per fed sample, what the box's line said (the arrays a ReplayReport keeps)."""

    out_nm: np.ndarray  # (n, axes) corrections; 0 where no line arrived
    status: np.ndarray  # (n,) status word; -1 where no line arrived
    seq: np.ndarray  # (n,) seq of the sample's line; -1 where none
    session: np.ndarray  # (n,) session (power-up) of the sample's line; -1 where none
    got: np.ndarray  # (n,) a line arrived

    @staticmethod
    def empty(n: int, n_axes: int) -> _Received:
        return _Received(np.zeros((n, n_axes), dtype=np.int64), np.full(n, -1, dtype=np.int64),
                         np.full(n, -1, dtype=np.int64), np.full(n, -1, dtype=np.int64),
                         np.zeros(n, dtype=bool))


def _session_health(rep: ReplayReport, s_index: int, session: Session) -> None:
    """The session ran to its end, or was cut on purpose (a power cut)."""
    if session.error:
        rep.problems_fatal = True
        rep.note(f"session {s_index} (from sample {session.first_sample}): {session.error}")
    elif not session.power_cut and session.exit_code != 0:
        rep.problems_fatal = True
        rep.note(f"session {s_index} (from sample {session.first_sample}): the firmware "
                 f"exited with code {session.exit_code} (crash or feed error)")


def _zero_replies(rep: ReplayReport, s_index: int, session: Session,
                  zero_at: Sequence[int], refused: Sequence[int] = ()) -> None:
    """Each ZERO sent in this session was answered with the sample before it, or refused
    (HOLDING) where the twin says an axis held at that sample."""
    zs = [z for z in zero_at if session.first_sample <= z < session.first_sample +
          max(session.n_fed, 1)]
    replies = [decode(a) for a in session.zero_acks]
    acks = [r.reason if isinstance(r, ErrorReply) else r.value - session.seq0
            for r in replies]
    want_acks = ["HOLDING" if z in refused else
                 (z - session.first_sample - 1 if session.seq0 + z - session.first_sample > 0
                  else 0) for z in zs]
    if acks != want_acks:
        rep.status_mismatches += 1
        rep.note(f"session {s_index}: ZERO replies name samples {acks}, expected "
                 f"{want_acks} (the latest sample before each ZERO)")


def _check_lines(rep: ReplayReport, s_index: int, session: Session, lines: SessionLines,
                 exp: Expected, axes: Sequence[str], rx: _Received) -> None:
    """1. Every sample line against the twin, bit for bit: corrections, status and the
    temperature codes the box says it read; the first line of each seq counts."""
    n_axes = len(axes)
    seen: set[int] = set()
    for line in lines.samples:
        if line.seq >= session.n_fed or line.seq in seen:
            continue
        seen.add(line.seq)
        i = session.first_sample + line.seq
        j = line.seq
        rx.got[i] = True
        rx.status[i] = line.status
        rx.seq[i], rx.session[i] = line.seq, s_index
        want_out = exp.out_nm[j]
        if len(line.corrections_nm) != want_out.shape[0]:
            rep.mismatches += 1
            rep.note(f"sample {i}: {len(line.corrections_nm)} corrections, expected "
                     f"{want_out.shape[0]}")
        else:
            diff = np.abs(np.asarray(line.corrections_nm, dtype=np.int64) - want_out)
            if n_axes and want_out.shape[0] == n_axes:
                rx.out_nm[i] = line.corrections_nm
            if diff.any():
                rep.mismatches += 1
                rep.max_abs_diff_nm = max(rep.max_abs_diff_nm, int(diff.max()))
                for a, d in enumerate(diff):
                    if d and a < n_axes:
                        ax = rep.axes[axes[a]]
                        ax.mismatches += 1
                        ax.max_abs_diff_nm = max(ax.max_abs_diff_nm, int(d))
                rep.note(f"sample {i}: corrections {list(line.corrections_nm)} nm, twin "
                         f"{want_out.tolist()} nm")
        if line.status != int(exp.status[j]):
            rep.status_mismatches += 1
            rep.note(f"sample {i}: status {line.status:04X} ({status_text(line.status)}), "
                     f"expected {int(exp.status[j]):04X} ({status_text(int(exp.status[j]))})")
        if list(line.temp_codes) != exp.codes[j].tolist():
            rep.code_mismatches += 1
            rep.note(f"sample {i}: temperature codes {list(line.temp_codes)}, fed "
                     f"{exp.codes[j].tolist()}")


def _float_differences(session: Session, exp: Expected, model: dict, feed: Feed,
                       codes_fed: np.ndarray, rx: _Received) -> tuple[np.ndarray, int] | None:
    """2. The float model against the box, per axis (largest |difference| in um, samples
    compared), where the box outputs the model's value directly and no fault has touched
    the filter states yet in this session; None when no sample qualifies."""
    n_axes = len(feed.axes)
    if not (n_axes and exp.out_nm.shape[1] == n_axes and session.n_fed):
        return None
    if session.wdt_reset or session.resumed:
        # it continues the filter states of the session before it (warm reset, RESUME), which
        # a float model started at this session cannot know: the twin judges it bit for bit
        return None
    rows = slice(session.first_sample, session.first_sample + session.n_fed)
    local = np.arange(session.n_fed)
    clean = np.cumprod(exp.computed.all(axis=1)).astype(bool)
    direct = clean & ((exp.status & (HOLD | SLEW | CLAMP | NO_DATA | MODEL_BAD)) == 0)
    direct &= rx.got[rows]
    if not direct.any():
        return None
    # the float model on what the box's model got (the guard's held codes), and the box's
    # output with its ZERO reference added back
    float_codes = codes_fed.copy()
    if exp.model_codes is not None:
        float_codes[rows] = exp.model_codes
    pred = float_predictions(model, feed, float_codes, rows)
    ref = exp.ref_nm if exp.ref_nm is not None else np.zeros_like(exp.out_nm)
    # and without the in-service estimate (MEAS, issue 42), which the float model lacks
    if exp.bias_nm is not None and exp.bias_nm.shape == ref.shape:
        ref = ref - exp.bias_nm
    d = np.abs((rx.out_nm[rows][local[direct]] + ref[local[direct]]) / 1000.0
               - pred[local[direct]])
    return d.max(axis=0), int(direct.sum())


def _steps(rep: ReplayReport, s_index: int, session: Session, exp: Expected,
           axes: Sequence[str], rx: _Received) -> None:
    """The output's steps between consecutive sample lines of one power-up, per axis, against
    the axis's step limit (``AxisReport.max_step_nm``).

    A ZERO moves the output by the change of datum (the new reference), which is no step of
    the correction: the step judged is that of output + reference, the reference in force as
    the twin computes it (the box does not send it; check 1 holds the box to the twin's
    output). A line lost in between allows one limit per missing period."""
    n_axes = len(axes)
    if not (n_axes and session.n_fed and exp.out_nm.shape[1] == n_axes):
        return
    rows = np.arange(session.first_sample, session.first_sample + session.n_fed)
    rows = rows[rx.got[rows] & (rx.session[rows] == s_index)]
    if rows.size < 2:
        return
    seq = rx.seq[rows]
    ref = exp.ref_nm[seq] if exp.ref_nm is not None else 0
    value = rx.out_nm[rows] + ref
    gap = np.diff(seq)[:, None]
    step = -(-np.abs(np.diff(value, axis=0)) // gap)  # per period, rounded up
    for a, name in enumerate(axes):
        ax = rep.axes[name]
        col = step[:, a]
        ax.largest_step_nm = max(ax.largest_step_nm or 0, int(col.max()))
        if ax.max_step_nm is None:
            continue
        over = np.flatnonzero(col > ax.max_step_nm)
        if over.size:
            ax.steps_over_limit += int(over.size)
            first = int(rows[over[0] + 1])
            ax.first_step_over = first if ax.first_step_over is None else \
                min(ax.first_step_over, first)


def step_limits_nm(model: dict) -> dict[str, int]:
    """Each axis's output step limit as the header carries it (codegen's quantisation)."""
    from thermal_comp.codegen.quantise import quantise

    return {ax.name: ax.max_step_nm for ax in quantise(model).axes}


def _residuals(rep: ReplayReport, feed: Feed, rx: _Received, zeroed: bool) -> None:
    """3. What the box's corrections leave of the measured drift, per axis. When the box
    zeroes (at power-up, or by ZERO) its output is already the change since then; otherwise
    it is referenced here like the measurement."""
    if not rx.got.any():
        return
    for a, name in enumerate(feed.axes):
        if name not in feed.measured:
            continue
        ax = rep.axes[name]
        meas = feed.measured[name][rx.got]
        box = rx.out_nm[rx.got, a] / 1000.0
        comp = meas - (box if zeroed else feed.reference.apply(box))
        ax.raw_rms_um = float(np.sqrt(np.mean(meas ** 2)))
        ax.raw_peak_um = float(np.max(np.abs(meas)))
        ax.compensated_rms_um = float(np.sqrt(np.mean(comp ** 2)))
        ax.compensated_peak_um = float(np.max(np.abs(comp)))


def judge(capture: Capture, expected: list[Expected], feed: Feed, model: dict,
          bounds_um: dict[str, float], judging: Judging | None = None,
          zero_at: Sequence[int] = (), box_zeroes: bool = False,
          step_limits: dict[str, int] | None = None) -> ReplayReport:
    """Compare every session's lines with its expectation and compute the residuals.

    ``zero_at``: samples before which ZERO was sent (each reply must name the sample before).
    ``box_zeroes``: the header was built with TCM_ZERO_AT_POWERUP (the box's output is already
    the change since its start). ``step_limits``: each axis's output step limit in nm
    (default: the model's, as codegen puts it into the header).
    """
    n = capture.n_samples
    n_axes = len(feed.axes)
    rep = ReplayReport(samples=n, sessions=len(capture.sessions), judging=judging)
    limits = step_limits_nm(model) if step_limits is None else step_limits
    rep.axes = {a: AxisReport(a, bound_um=bounds_um.get(a), max_step_nm=limits.get(a))
                for a in feed.axes}
    rx = _Received.empty(n, n_axes)
    codes_fed = np.asarray(capture.codes_fed, dtype=np.int64)
    float_diff = np.zeros(n_axes)
    float_count = 0

    for s_index, (session, exp) in enumerate(zip(capture.sessions, expected, strict=True)):
        _session_health(rep, s_index, session)
        lines = decode_session(session)
        rep.bad_lines += len(lines.bad)
        for b in lines.bad:
            rep.note(f"session {s_index}: undecodable line: {b}")
        rep.errors += [e.reason for e in lines.errors]
        _zero_replies(rep, s_index, session, zero_at, exp.zero_refused)
        if session.seq0:  # resumed after a warm reset: seq counts on from before it
            lines.samples = [replace(s, seq=s.seq - session.seq0) for s in lines.samples]
        lost, dup, reord = sequence_problems([s.seq for s in lines.samples], session.n_fed)
        rep.lost += lost
        rep.duplicated += dup
        rep.reordered += reord
        if lost or dup or reord:
            rep.note(f"session {s_index}: {lost} lost, {dup} duplicated, {reord} reordered "
                     f"sample lines")
        _check_lines(rep, s_index, session, lines, exp, feed.axes, rx)
        _steps(rep, s_index, session, exp, feed.axes, rx)
        found = _float_differences(session, exp, model, feed, codes_fed, rx)
        if found is not None:
            float_diff = np.maximum(float_diff, found[0])
            float_count += found[1]

    ss = capture.sessions
    off = sum(s.first_sample - (p.first_sample + p.n_fed)  # the box was off (Restart.off)
              for p, s in zip(ss[:-1], ss[1:], strict=True) if s.battery)
    never_fed = n - sum(s.n_fed for s in capture.sessions) - off
    if never_fed > 0:  # the replay stopped early: those samples got no line either
        rep.lost += never_fed
        rep.note(f"{never_fed} samples were never fed (the replay stopped early)")
    rep.received = int(rx.got.sum())
    rep.fw_out_nm, rep.fw_status = rx.out_nm, rx.status
    rep.fw_seq, rep.fw_session = rx.seq, rx.session
    for a, name in enumerate(feed.axes):
        ax = rep.axes[name]
        if float_count:
            ax.float_max_diff_um, ax.float_samples = float(float_diff[a]), float_count
            if ax.bound_um is not None and ax.float_max_diff_um > ax.bound_um + 1e-9:
                rep.note(f"axis {name}: float model differs by {ax.float_max_diff_um:.6g} um, "
                         f"bound {ax.bound_um:.6g} um")
    _residuals(rep, feed, rx, box_zeroes or bool(zero_at))
    for reason in rep.judgement_reasons():  # after the residuals: they are judged too
        rep.note(reason)
    return rep


def sample_lines(capture: Capture) -> list[bytes]:
    """Every sample line of a capture, in order, as sent (all sessions)."""
    return [raw for s in capture.sessions for raw in s.lines if raw.startswith(b"$C,")]


def capture_differences(a: Capture, b: Capture) -> tuple[int, str]:
    """(number of sample lines that differ byte for byte, first difference) of two replays."""
    la, lb = sample_lines(a), sample_lines(b)
    diff = sum(1 for x, y in zip(la, lb, strict=False) if x != y) + abs(len(la) - len(lb))
    first = ""
    for i, (x, y) in enumerate(zip(la, lb, strict=False)):
        if x != y:
            first = f"sample line {i}: {x!r} vs {y!r}"
            break
    else:
        if len(la) != len(lb):
            first = f"{len(la)} sample lines vs {len(lb)}"
    return diff, first


def write_box_csv(report: ReplayReport, feed: Feed, path: str | Path) -> Path:
    """What the box sent for every sample: ``time_s, session, seq, status, status_names`` and
    the correction of each axis in um (empty where no line arrived). Anyone can look at a
    glitch's effect without the runner."""
    import csv

    path = Path(path)
    n = report.samples
    status = report.fw_status if report.fw_status is not None else np.full(n, -1)
    seq = report.fw_seq if report.fw_seq is not None else np.full(n, -1)
    session = report.fw_session if report.fw_session is not None else np.full(n, -1)
    out = report.fw_out_nm if report.fw_out_nm is not None else np.zeros((n, len(feed.axes)))
    time_s = feed.run.time_s
    with path.open("w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(["time_s", "session", "seq", "status", "status_names",
                    *[f"{a}" for a in feed.axes]])
        for i in range(n):
            if status[i] < 0:
                w.writerow([f"{time_s[i]:.6g}", "", "", "", "", *[""] * len(feed.axes)])
                continue
            w.writerow([f"{time_s[i]:.6g}", int(session[i]), int(seq[i]),
                        f"{int(status[i]):04X}", status_text(int(status[i])),
                        *[f"{v / 1000:.3f}" for v in out[i]]])
    return path

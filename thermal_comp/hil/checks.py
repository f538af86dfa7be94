"""Judge a captured replay against the host's expectation: the checks, line by line.

Four checks: 1. every correction equals the integer twin's (after the documented
output stage), bit for bit, and so do the status word and the echoed temperature codes;
2. the float model (contract/terms.py on the quantised temperatures) is within the bound codegen
proved, wherever the box outputs the model value directly; 3. no sample line is lost,
duplicated or reordered (``seq``); 4. the residual measured − correction beside the raw
displacement, per axis, RMS and peak. The lines are decoded with contract/protocol.py only.
The report they fill in, and its judgement (``Judging``), live in ``hil.replay_report``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from thermal_comp.contract.model_file import ModelSpec, spec_of
from thermal_comp.contract.protocol import ErrorReply, Info, ProtocolError, Sample, decode
from thermal_comp.hil.expect import (
    CLAMP,
    HOLD,
    MODEL_BAD,
    NO_DATA,
    SLEW,
    Expected,
    status_text,
)
from thermal_comp.hil.feed import Feed
from thermal_comp.hil.replay_report import AxisReport, Judging, ReplayReport
from thermal_comp.hil.runner import Capture, Session
from thermal_comp.host.fitting import design_matrix

__all__ = ["AxisReport", "Judging", "ReplayReport", "SessionLines", "decode_session",
           "float_predictions", "judge", "sequence_problems", "step_limits_nm"]


@dataclass
class SessionLines:
    """A session's lines, decoded and sorted by kind."""

    samples: list[Sample] = field(default_factory=list)
    info: list[Info] = field(default_factory=list)
    errors: list[ErrorReply] = field(default_factory=list)
    other: list[object] = field(default_factory=list)
    bad: list[str] = field(default_factory=list)



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


def float_predictions(model: ModelSpec, feed: Feed, codes: np.ndarray, rows: slice
                      ) -> np.ndarray:
    """The float model (contract/terms.py) on the quantised inputs of one session: (n, axes) um."""
    cols: dict[str, np.ndarray] = {}
    for c, name in enumerate(model.sensors):
        cols[name] = codes[rows, c].astype(float) / 128.0
    for k, name in enumerate(model.aux_names):
        cols[name] = feed.aux[rows, k].astype(float)
    out = []
    for axis in feed.axes:
        ax = model.axis(axis)
        x = design_matrix(list(ax.terms), cols, model.sample_period_s) if cols \
            else np.empty((rows.stop - rows.start, 0))
        out.append(ax.intercept + x @ np.array(ax.coefs))
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


def _float_differences(session: Session, exp: Expected, model: ModelSpec, feed: Feed,
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


def step_limits_nm(model: Mapping | ModelSpec) -> dict[str, int]:
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


def _judge_session(rep: ReplayReport, s_index: int, session: Session, exp: Expected,
                   feed: Feed, model: ModelSpec, codes_fed: np.ndarray, zero_at: Sequence[int],
                   rx: _Received) -> tuple[np.ndarray, int] | None:
    """One power-up's lines: health, ZERO replies, sequence, the twin, the steps; returns the
    float model's differences (``_float_differences``) for the caller to gather."""
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
    return _float_differences(session, exp, model, feed, codes_fed, rx)


def _never_fed(rep: ReplayReport, capture: Capture) -> None:
    """Samples the replay never fed (it stopped early) got no line either: lost."""
    ss = capture.sessions
    off = sum(s.first_sample - (p.first_sample + p.n_fed)  # the box was off (Restart.off)
              for p, s in zip(ss[:-1], ss[1:], strict=True) if s.battery)
    never_fed = capture.n_samples - sum(s.n_fed for s in capture.sessions) - off
    if never_fed > 0:  # the replay stopped early: those samples got no line either
        rep.lost += never_fed
        rep.note(f"{never_fed} samples were never fed (the replay stopped early)")


def _float_verdict(rep: ReplayReport, axes: Sequence[str], float_diff: np.ndarray,
                   float_count: int) -> None:
    """2. The float model's largest difference per axis against the bound codegen proved."""
    for a, name in enumerate(axes):
        ax = rep.axes[name]
        if float_count:
            ax.float_max_diff_um, ax.float_samples = float(float_diff[a]), float_count
            if ax.bound_um is not None and ax.float_max_diff_um > ax.bound_um + 1e-9:
                rep.note(f"axis {name}: float model differs by {ax.float_max_diff_um:.6g} um, "
                         f"bound {ax.bound_um:.6g} um")


def judge(capture: Capture, expected: list[Expected], feed: Feed, model: Mapping | ModelSpec,
          bounds_um: dict[str, float], judging: Judging | None = None,
          zero_at: Sequence[int] = (), box_zeroes: bool = False,
          step_limits: dict[str, int] | None = None) -> ReplayReport:
    """Compare every session's lines with its expectation and compute the residuals.

    ``zero_at``: samples before which ZERO was sent (each reply must name the sample before).
    ``box_zeroes``: the header was built with TCM_ZERO_AT_POWERUP (the box's output is already
    the change since its start). ``step_limits``: each axis's output step limit in nm
    (default: the model's, as codegen puts it into the header). ``model``: the typed view
    (``ReplaySetup.spec``), or the dict.
    """
    model = spec_of(model)
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
        found = _judge_session(rep, s_index, session, exp, feed, model, codes_fed, zero_at, rx)
        if found is not None:
            float_diff = np.maximum(float_diff, found[0])
            float_count += found[1]

    _never_fed(rep, capture)
    rep.received = int(rx.got.sum())
    rep.fw_out_nm, rep.fw_status = rx.out_nm, rx.status
    rep.fw_seq, rep.fw_session = rx.seq, rx.session
    _float_verdict(rep, feed.axes, float_diff, float_count)
    _residuals(rep, feed, rx, box_zeroes or bool(zero_at))
    for reason in rep.judgement_reasons():  # after the residuals: they are judged too
        rep.note(reason)
    return rep

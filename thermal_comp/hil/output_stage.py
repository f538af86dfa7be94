"""The box's axis output stage over a session, as the host's twin of the firmware.

``firmware/include/axis_output.h`` (ZERO reference, hold on a fault, the per-axis step limit,
walk back at the slew limit, clamp) and app.c's answers to MEAS with the in-service estimator
(issue 42): per sample, ``codegen.fixed.AxisOutput`` and ``codegen.estimator`` as the box runs
them, apart from which inputs are valid (``hil.expect``), so either can be checked alone.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from thermal_comp.codegen import estimator as est
from thermal_comp.codegen.fixed import AxisOutput
from thermal_comp.contract.protocol import MeasReply, Status
from thermal_comp.hil.box_config import OutputConfig

CLAMP, NO_REF = Status.CLAMP, Status.NO_REF


@dataclass
class ServiceOut:
    """What the in-service estimator twin produced over a session (output_stage_ref)."""

    replies: list[MeasReply]
    bias_nm: np.ndarray


# MEAS (issue 42): a reading of a sample with an incomplete reference / a held axis
_MEAS_OK, _MEAS_NO_REF, _MEAS_HOLDING = 0, 1, 2


def _sat32(v: int) -> int:
    return max(-(2**31), min(2**31 - 1, v))


def _meas_reply(axis: int, seq: int, nm: int, latest: int, ring_start: int, ring: dict,
                states: list, params: Sequence, no_reference: bool, window: int
                ) -> MeasReply:
    """The box's answer to ``MEAS axis nm seq`` before sample ``latest + 1`` (app.c
    handle_meas; the reasons in contract.protocol.MEAS_REASONS' order)."""
    box_seq = seq % 2**32
    if axis >= len(params) or params[axis] is None:
        return MeasReply(axis, box_seq, False, "AXIS" if axis >= len(params) else "OFF",
                         None, None, None)
    st, pa = states[axis], params[axis]

    def refuse(reason: str) -> MeasReply:
        return MeasReply(axis, box_seq, False, reason, None, st.bias_nm, (st.p_q8 + 128) >> 8)

    held = max(ring_start, latest - window + 1) <= seq <= latest
    if no_reference or (held and ring[seq][1][axis] == _MEAS_NO_REF):
        return refuse("NO_REF")
    if not held:
        return refuse("SEQ")
    if ring[seq][1][axis] != _MEAS_OK or ring[latest][1][axis] != _MEAS_OK:
        return refuse("HOLDING")
    m = est.measure(st, pa, nm, ring[seq][0][axis])
    return MeasReply(axis, box_seq, m.accepted, (m.reason or None) if m.accepted else "GATE",
                     st.last_innovation_nm, st.bias_nm, (st.p_q8 + 128) >> 8)


@dataclass
class _StageRun:
    """The output stage's state while it walks a session sample by sample: the axes, their
    estimators, the samples the box remembers for MEAS, and what it sent."""

    cfg: OutputConfig
    axes: list[AxisOutput]
    params: list
    out: np.ndarray  # (n, axes) what the sample line carries
    ref: np.ndarray  # (n, axes) the ZERO reference in force
    bias: np.ndarray  # (n, axes) the in-service estimate at each sample
    bits: np.ndarray  # (n,) status bits
    states: list = field(default_factory=list)
    ring: dict[int, tuple[list[int], list[int]]] = field(default_factory=dict)
    ring_start: int = 0
    referenced: bool = False
    accepted: list[int] = field(default_factory=list)
    replies: list[MeasReply] = field(default_factory=list)

    @classmethod
    def start(cls, n: int, n_axes: int, cfg: OutputConfig, step: int,
              track: Sequence[int] | None, params: list) -> _StageRun:
        axes = [AxisOutput(cfg.max_abs_nm, step, (2**31 - 1) if track is None else int(track[a]),
                           cfg.zero_samples, cfg.cold_start_slew) for a in range(n_axes)]
        run = cls(cfg, axes, params, np.zeros((n, n_axes), dtype=np.int64),
                  np.zeros((n, n_axes), dtype=np.int64), np.zeros((n, n_axes), dtype=np.int64),
                  np.zeros(n, dtype=np.int64))
        run.reset_states()
        return run

    def reset_states(self) -> None:
        self.states = [est.reset(p) if p is not None else est.FixedState() for p in self.params]

    def zero(self, i: int) -> None:
        """An accepted ZERO before sample ``i``: the datum takes the bias too, the estimators
        start again and the box forgets the samples before it."""
        self.accepted.append(i)
        self.referenced = True
        for a, ax in enumerate(self.axes):
            if ax.has_output and self.states[a].bias_nm:  # the datum takes the bias too
                moved = ax.out_nm - self.states[a].bias_nm
                if abs(moved) > self.cfg.max_abs_nm:
                    self.bits[i] |= CLAMP
                    moved = self.cfg.max_abs_nm if moved > 0 else -self.cfg.max_abs_nm
                ax.out_nm = moved
            ax.zero()
        self.reset_states()
        self.ring_start = i

    def sample(self, i: int, ok_row: list, val_row: list, no_ref: bool, ticks: bool) -> None:
        """Sample ``i`` through every axis; remembered for MEAS (value less reference, and
        whether a reading of it could be applied)."""
        n_axes = len(self.axes)
        entry: tuple[list[int], list[int]] = ([0] * n_axes, [0] * n_axes)
        for a, ax in enumerate(self.axes):
            if self.params[a] is not None and ticks:
                est.tick(self.states[a], self.params[a])
            valid = bool(ok_row[a])
            value = int(val_row[a])
            self.bias[i, a] = self.states[a].bias_nm
            for name in ax.update(valid and not no_ref, _sat32(value + self.states[a].bias_nm)):
                self.bits[i] |= Status[name]
            self.out[i, a], self.ref[i, a] = ax.out_nm, ax.ref_nm
            entry[0][a] = _sat32(value - ax.ref_nm)
            entry[1][a] = (_MEAS_NO_REF if no_ref or ax.zeroing else
                           _MEAS_HOLDING if not valid or ax.walking else _MEAS_OK)
        self.ring[i] = entry


def output_stage_ref(computed_nm: np.ndarray, computed: np.ndarray, cfg: OutputConfig,
                     step: int, track: Sequence[int] | None = None,
                     zero_before: Sequence[int] = (), needs_ref: bool = False,
                     resets: Sequence[int] = (), service: Sequence | None = None,
                     meas: dict[int, list[tuple[int, int, int, bool]]] | None = None,
                     meas_samples: int = 4, svc_out: ServiceOut | None = None
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[int]]:
    """The axis output stage over a session (codegen.fixed.AxisOutput per axis):
    (out_nm [n, axes], status bits [n], reference [n, axes], accepted ZEROs).

    ``step``: the walk-back step (BOX_SLEW_NM_PER_S per period); ``track``: each axis's
    step limit from the header (None: unlimited while tracking); ``zero_before``: samples
    before which ZERO is sent (0 = before the first); the box refuses one (HOLDING) when an
    axis's inputs were faulted, or an axis walked (SLEW), at the sample before it (not after
    a reset: nothing sampled).
    ``needs_ref``: a start-referenced model after a cold power-up: until the first accepted
    ZERO every axis holds (NO_REF). ``resets``: samples before which a warm reset happened.
    ``service``: per axis its estimator parameters (codegen.estimator.FixedParams, None: no
    service block); ``meas``: sample -> the readings sent before it, (axis, nm, seq,
    after_zero: sent after a ZERO at the same point); the answers and the bias per sample go
    to ``svc_out`` (docs/service.md, "On the box")."""
    n, n_axes = computed_nm.shape
    zeros, warm = set(zero_before), set(resets)
    ok_rows = computed.tolist()
    val_rows = computed_nm.tolist()
    params = list(service) if service is not None else [None] * n_axes
    run = _StageRun.start(n, n_axes, cfg, step, track, params)
    meas = meas or {}
    for i in range(n):
        zero_now = i in zeros and (i == 0 or i in warm or (
            all(ok_rows[i - 1]) and not run.bits[i - 1] & int(Status.SLEW)))
        if i in warm:
            run.ring_start = i  # the box forgets its samples over a reset (not retained)
        for axis, nm, seq, after_zero in meas.get(i, []):
            run.replies.append(_meas_reply(axis, seq, nm, i - 1, run.ring_start, run.ring,
                                           run.states, params,
                                           (needs_ref and not run.referenced) or
                                           (after_zero and zero_now), meas_samples))
        if zero_now:
            run.zero(i)
        no_ref = needs_ref and not run.referenced
        if no_ref:
            run.bits[i] |= NO_REF
        run.sample(i, ok_rows[i], val_rows[i], no_ref, i > 0 and not zero_now)
        run.ring.pop(i - meas_samples, None)
    if svc_out is not None:
        svc_out.replies, svc_out.bias_nm = run.replies, run.bias
    return run.out, run.bits, run.ref, run.accepted


def output_stage(computed_nm: np.ndarray, computed: np.ndarray, cfg: OutputConfig,
                 step: int, track: Sequence[int] | None = None,
                 zero_before: Sequence[int] = ()) -> tuple[np.ndarray, np.ndarray]:
    """The axis output logic over a session: (out_nm [n, axes], status bits [n])."""
    out, bits, _, _ = output_stage_ref(computed_nm, computed, cfg, step, track, zero_before)
    return out, bits

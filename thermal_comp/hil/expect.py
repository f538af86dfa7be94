"""What the box should send for each sample, computed on the host only.

The model part is the integer twin ``codegen.fixed.FixedModel`` (bit-exact by contract). Around
it sit the parts of the application the wire protocol and the firmware's documented behaviour
define: which channel is faulted (chip fault status register, valid code range), the
plausibility guard of ``firmware/include/channel_guard.h`` (IMPLAUSIBLE: a glitch held at the
last good code, repeated ones a fault), the stuck check (one code ``max_still_samples`` times
in a row: a channel fault), which status bits that raises, and the output stage of
``firmware/include/axis_output.h`` (ZERO reference, hold on a fault, the per-axis step limit,
walk back at the slew limit, clamp) -- the guard and the output stage are the sample-by-sample
twins ``codegen.fixed.ChannelGuard`` / ``AxisOutput``. Configuration is read from
``box_config.h`` (the defaults the firmware is built with) plus any ``-D`` overrides passed
to the build (``hil.box_config``); the output stage itself is ``hil.output_stage``. Nothing
here looks at what the firmware sent.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from thermal_comp.codegen.fixed import (
    GUARD_FAULT,
    GUARD_HELD,
    GUARD_RUNAWAY_SAMPLES,
    ChannelGuard,
    FixedModel,
)
from thermal_comp.contract.protocol import (
    STATUS_BITS,
    ChannelFault,
    MeasReply,
    Status,
    status_names,
)
from thermal_comp.contract.terms import AUX_KINDS, TEMPERATURE_KINDS
from thermal_comp.hil.box_config import OutputConfig
from thermal_comp.hil.output_stage import ServiceOut, output_stage_ref

# The status word has one home, contract.protocol (docs/protocol.md); short names here.
MODEL_BAD, HOLD, SLEW, CLAMP = Status.MODEL_BAD, Status.HOLD, Status.SLEW, Status.CLAMP
RANGE, OPEN, TC_FAULT, AUX_FAULT = Status.RANGE, Status.OPEN, Status.TC_FAULT, Status.AUX_FAULT
WDT_RESET, NO_DATA, EXTRAP = Status.WDT_RESET, Status.NO_DATA, Status.EXTRAP
REFERENCED, IMPLAUSIBLE = Status.REFERENCED, Status.IMPLAUSIBLE
NO_REF, BEYOND = Status.NO_REF, Status.BEYOND
STATUS_NAMES = STATUS_BITS
SR_OPEN = int(ChannelFault.OPEN)  # MAX31856 fault status register bit OPEN



def status_text(status: int) -> str:
    names = status_names(status)
    return "|".join(names) if names else "-"


@dataclass
class Expected:
    """Per-sample expectation for one power-up of the box."""

    out_nm: np.ndarray  # (n, n_axes) int64: what the sample line carries
    computed_nm: np.ndarray  # (n, n_axes): the model's value (twin), before the output stage
    computed: np.ndarray  # (n, n_axes) bool: the model computed the axis at this sample
    status: np.ndarray  # (n,) int: expected status word
    codes: np.ndarray  # (n, n_channels): the codes the chips report (echoed in the line)
    model_codes: np.ndarray | None = None  # (n, n_channels): what the model got (guarded)
    ref_nm: np.ndarray | None = None  # (n, axes): the ZERO reference in force (0 without)
    zero_refused: tuple[int, ...] = ()  # samples before which ZERO was refused (HOLDING)
    meas_replies: tuple[MeasReply, ...] = ()  # the $M answers to MEAS, in order
    bias_nm: np.ndarray | None = None  # (n, axes): the estimate added at each sample



def aux_fault_value(aux) -> int:
    """What the box hands the model for an aux input it could not read (app.c sample_aux):
    a value just outside the declared range, so the runtime judges it invalid."""
    lo, hi = int(aux.min), int(aux.max)
    return lo - 1 if lo > -2**31 else (hi + 1 if hi < 2**31 - 1 else 0)


def channel_faults(codes: np.ndarray, sr: np.ndarray, min_code: np.ndarray,
                   max_code: np.ndarray, window_lo: np.ndarray | None = None,
                   window_hi: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(valid [n, ch], status bits [n]) from the chips' SR, the channels' valid ranges and
    their training windows.

    A chip reporting a fault is a fault of the chip (OPEN / TC_FAULT), whatever its code; only
    a chip without fault is range-checked (RANGE); only a valid code is window-checked
    (EXTRAP: the model extrapolates, the axis is still corrected).
    """
    chip_fault = sr != 0
    out_of_range = ~chip_fault & ((codes < min_code) | (codes > max_code))
    valid = ~chip_fault & ~out_of_range
    bits = np.zeros(codes.shape[0], dtype=np.int64)
    bits |= np.where((sr & SR_OPEN).any(axis=1), OPEN, 0)
    bits |= np.where((sr & ~SR_OPEN & 0xFF).any(axis=1), TC_FAULT, 0)
    bits |= np.where(out_of_range.any(axis=1), RANGE, 0)
    if window_lo is not None and window_hi is not None:
        beyond = valid & ((codes < window_lo) | (codes > window_hi))
        bits |= np.where(beyond.any(axis=1), EXTRAP, 0)
    return valid, bits


def still_runs(codes: np.ndarray, readable: np.ndarray) -> np.ndarray:
    """[n, ch]: how many valid readings in a row, this one included, carried this code (0 on
    a sample whose reading was not valid: a chip fault or an out-of-range code ends a run),
    saturating at 65535 like the box's uint16_t counter."""
    n = codes.shape[0]
    if n == 0:
        return np.zeros(codes.shape, dtype=np.int64)
    same = np.zeros(codes.shape, dtype=bool)
    same[1:] = readable[1:] & readable[:-1] & (codes[1:] == codes[:-1])
    idx = np.arange(n)[:, None]
    start = np.maximum.accumulate(np.where(same, 0, idx), axis=0)  # first sample of the run
    return np.where(readable, np.minimum(idx - start + 1, 65535), 0)


def stuck_channels(codes: np.ndarray, readable: np.ndarray,
                   max_still: Sequence[int]) -> np.ndarray:
    """[n, ch] bool: the channel is stuck (docs/firmware.md): a valid reading whose code the
    channel has carried ``max_still`` readings in a row or more; ``max_still`` 0: no check."""
    limit = np.asarray(max_still, dtype=np.int64)
    return readable & (limit > 0) & (still_runs(codes, readable) >= limit)


def guard_channels(codes: np.ndarray, in_range: np.ndarray, max_step: Sequence[int],
                   fault_after: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The plausibility guard over a session (codegen.fixed.ChannelGuard per channel).

    ``in_range`` [n, ch]: the chip reported no fault and the code is in its valid range.
    Returns (model codes [n, ch], valid [n, ch], implausible [n, ch]): the code the model gets
    (the channel's last good code while a glitch is held), whether the channel counts as
    valid, and whether the guard rejected the reading (held or faulted).
    """
    model_codes = codes.copy()
    valid = in_range.copy()
    implausible = np.zeros(codes.shape, dtype=bool)
    for c in range(codes.shape[1]):
        w = GUARD_RUNAWAY_SAMPLES
        col_c = codes[:, c]
        if in_range[:, c].all() and (codes.shape[0] < 2 or (
                np.abs(np.diff(col_c)).max() <= max_step[c] and (
                    codes.shape[0] <= w or np.abs(col_c[w:] - col_c[:-w]).max()
                    <= max_step[c] * (w // 2 + 1)))):
            continue  # every change plausible, no runaway, no fault: the guard never acts
        g = ChannelGuard()
        col, ok = codes[:, c].tolist(), in_range[:, c].tolist()
        for i in range(len(col)):
            if not ok[i]:
                g.lost()
                continue
            verdict, use = g.check(col[i], max_step[c], fault_after)
            if verdict != 0:
                implausible[i, c] = True
                if verdict == GUARD_FAULT:
                    valid[i, c] = False
                elif verdict == GUARD_HELD:
                    model_codes[i, c] = use
    return model_codes, valid, implausible


def _input_bits(twin: FixedModel, codes: np.ndarray, aux: np.ndarray, sr: np.ndarray,
                wdt_reset: bool, model_bad: bool, warm_resets: Sequence[int]
                ) -> tuple[np.ndarray, np.ndarray]:
    """(in range [n, ch], status bits [n]) before the guard: chip faults, valid ranges, the
    aux inputs' ranges, and the sticky bits of the power-up (WDT_RESET, MODEL_BAD)."""
    m = twin.model
    n = codes.shape[0]
    lo = np.array([c.min_code for c in m.channels], dtype=np.int64)
    hi = np.array([c.max_code for c in m.channels], dtype=np.int64)
    in_range, bits = channel_faults(codes, sr, lo, hi)
    if m.aux:
        alo = np.array([a.min for a in m.aux], dtype=np.int64)
        ahi = np.array([a.max for a in m.aux], dtype=np.int64)
        bits |= np.where(((aux < alo) | (aux > ahi)).any(axis=1), AUX_FAULT, 0)
    sticky = (WDT_RESET if wdt_reset else 0) | (MODEL_BAD if model_bad else 0)
    bits |= sticky
    if warm_resets:
        bits |= np.where(np.arange(n) >= min(warm_resets), int(WDT_RESET), 0)
    return in_range, bits


def _model_bad_expected(codes: np.ndarray, in_range: np.ndarray, bits: np.ndarray,
                        wlo: np.ndarray, whi: np.ndarray, zeros: list[int],
                        meas: dict[int, list[tuple[int, int, int, bool]]] | None) -> Expected:
    """A box that refused its model (MODEL_BAD): no corrections at all, no guard, the
    temperatures still reported, every MEAS answered OFF."""
    n = codes.shape[0]
    if zeros:  # REFERENCED from the first sample of the first reference on
        bits |= np.where(np.arange(n) >= zeros[0], int(REFERENCED), 0)
    bits |= np.where((in_range & ((codes < wlo) | (codes > whi))).any(axis=1), EXTRAP, 0)
    empty = np.zeros((n, 0), dtype=np.int64)
    off = tuple(MeasReply(a, s % 2**32, False, "OFF", None, None, None)
                for i in sorted(meas or {}) for a, _, s, _ in (meas or {})[i])
    return Expected(empty, empty, empty.astype(bool), bits, codes, codes, empty,
                    meas_replies=off)


def expect_session(twin: FixedModel, codes: np.ndarray, aux: np.ndarray, sr: np.ndarray,
                   cfg: OutputConfig, wdt_reset: bool = False,
                   model_bad: bool = False, zero_before: Sequence[int] = (),
                   zero_at_powerup: bool = False, warm_resets: Sequence[int] = (),
                   meas: dict[int, list[tuple[int, int, int, bool]]] | None = None,
                   meas_samples: int = 4) -> Expected:
    """Expected lines for samples fed to one box from a cold power-up, through any number of
    warm resets (which it survives: docs/firmware.md, "Never worse than no compensation").

    ``codes`` [n, ch] are the chips' readings, ``sr`` [n, ch] their fault status registers,
    ``aux`` [n, n_aux] the aux inputs; ``zero_before``: local sample indices before which the
    CNC side sends ZERO; ``zero_at_powerup``: the header's TCM_ZERO_AT_POWERUP (a
    start-referenced model: NO_REF until a ZERO); ``wdt_reset``: the power-up itself was a
    watchdog reset; ``warm_resets``: samples before which the box reset by its watchdog and
    resumed (WDT_RESET from then on).
    """
    m = twin.model
    n = codes.shape[0]
    wlo = np.array([c.window_lo_code for c in m.channels], dtype=np.int64)
    whi = np.array([c.window_hi_code for c in m.channels], dtype=np.int64)
    in_range, bits = _input_bits(twin, codes, aux, sr, wdt_reset, model_bad, warm_resets)
    zeros = sorted(set(zero_before))
    if model_bad:  # no corrections at all, no guard, temperatures still reported
        return _model_bad_expected(codes, in_range, bits, wlo, whi, zeros, meas)
    # stuck: a channel fault like a chip fault (its axes hold, HOLD); the guard counts the
    # sample as lost, so the first reading that moves again is judged
    stuck = stuck_channels(codes, in_range, [c.max_still_samples for c in m.channels])
    model_codes, valid, implausible = guard_channels(
        codes, in_range & ~stuck, [c.max_step_code for c in m.channels], cfg.implausible_after)
    bits |= np.where(implausible.any(axis=1), int(IMPLAUSIBLE), 0)
    plausible = valid
    far_lo, far_hi = cfg.beyond_limits(wlo, whi)
    starts = list(zeros)  # the references a start-referenced model judges the change from
    for _ in range(len(zeros) + 2):  # which ZEROs the box accepts depends on BEYOND before
        if zero_at_powerup:
            far = referenced_beyond(model_codes, plausible, starts, far_hi - wlo)
        else:
            far = plausible & ((model_codes < far_lo) | (model_codes > far_hi))
        valid = plausible & ~far  # beyond what training supports: a fault, its axes hold
        computed_nm, computed = twin.evaluate_run(model_codes, aux if m.aux else None, valid,
                                                  return_mask=True)
        svc = ServiceOut([], np.zeros((n, len(m.axes)), dtype=np.int64))
        out, out_bits, ref, accepted = output_stage_ref(
            computed_nm, computed, cfg, cfg.step_nm(m.period_ms),
            [ax.max_step_nm for ax in m.axes], zeros, zero_at_powerup, warm_resets,
            [ax.service for ax in m.axes], meas, meas_samples, svc)
        if not zero_at_powerup or accepted == starts:
            break
        starts = accepted
    bits |= np.where(far.any(axis=1), int(BEYOND), 0)
    window = valid & ((model_codes < wlo) | (model_codes > whi))
    bits |= np.where(window.any(axis=1), EXTRAP, 0)
    if accepted:  # REFERENCED from the first sample of the first accepted reference on
        bits |= np.where(np.arange(n) >= accepted[0], int(REFERENCED), 0)
    refused = tuple(z for z in zeros if z not in accepted)
    return Expected(out, computed_nm, computed, bits | out_bits, codes, model_codes, ref,
                    refused, tuple(svc.replies), svc.bias_nm)


def referenced_beyond(codes: np.ndarray, plausible: np.ndarray, starts: Sequence[int],
                      limit: np.ndarray) -> np.ndarray:
    """BEYOND of a start-referenced model (app.c beyond_training): from each accepted
    reference on, a channel's first plausible reading is its reference reading; a later one
    whose change from it exceeds the window's span plus its margin (``limit`` per channel,
    far_hi - window_lo) is beyond."""
    n, n_ch = codes.shape
    far = np.zeros((n, n_ch), dtype=bool)
    bounds = [*sorted(starts), n]
    for lo, hi in zip(bounds[:-1], bounds[1:], strict=True):
        for ch in range(n_ch):
            seen = np.flatnonzero(plausible[lo:hi, ch])
            if seen.size == 0:
                continue
            r = lo + int(seen[0])
            change = np.abs(codes[r:hi, ch] - codes[r, ch])
            far[r:hi, ch] = plausible[r:hi, ch] & (change > limit[ch])
    return far


def axis_inputs(twin: FixedModel) -> list[tuple[set[int], set[int]]]:
    """Per axis: (channels, aux inputs) its terms read (which faults hold which axis)."""
    res = []
    for ax in twin.model.axes:
        res.append(({t.input for t in ax.terms if t.kind in TEMPERATURE_KINDS},
                    {t.input for t in ax.terms if t.kind in AUX_KINDS}))
    return res


def sr_timeline(n_samples: int, n_channels: int,
                faults: Sequence[tuple[int, int, int]]) -> np.ndarray:
    """Chip SR per sample from (at, channel, sr) events; an event holds until the next one."""
    sr = np.zeros((n_samples, n_channels), dtype=np.int64)
    for at, ch, value in sorted(faults, key=lambda f: f[0]):
        sr[at:, ch] = value
    return sr

"""Quantising the model's inputs: the sample period, the channels' codes, the aux ranges.

They come typed and checked (``contract.model_spec``, built by ``check_model``); each check
left here guards the number quantised beside it (docs/fixed-point.md): a valid range must give
codes inside the chip's 19 bits, a period whole milliseconds, and so on; the messages name the
key and the limit like contract.model_file's.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from fractions import Fraction

from thermal_comp.codegen.errors import CodegenError
from thermal_comp.codegen.qmodel import QAux, QChannel
from thermal_comp.contract.box import DEFAULT_CHANNEL_STEP_C_PER_S, DEFAULT_CHANNEL_STEP_MIN_C
from thermal_comp.contract.fixed_point import (
    CODE_MAX,
    CODE_MIN,
    EXTRAPOLATION_MARGIN,
    INT32_MAX,
    INT32_MIN,
    TEMP_FRAC_BITS,
    UINT32_MAX,
)
from thermal_comp.contract.model_spec import AuxSpec, ChannelSpec
from thermal_comp.contract.terms import TC_TYPES


def parse_channels(channels: Sequence[ChannelSpec], period_s: float) -> tuple[QChannel, ...]:
    """The channels' codes: valid range, training window, step and stuck limits."""
    out = []
    for ch in channels:
        where = f"channels[{ch.channel}]"
        lo = math.ceil(Fraction(ch.min_c) * 128)
        hi = math.floor(Fraction(ch.max_c) * 128)
        if not CODE_MIN <= lo <= hi <= CODE_MAX:
            raise CodegenError(
                f"{where} ({ch.sensor}): valid range {ch.min_c:g}..{ch.max_c:g} degC gives "
                f"codes {lo}..{hi}; it must be non-empty and inside the chip's 19-bit range "
                f"{CODE_MIN}..{CODE_MAX} ({CODE_MIN / 128:g}..{CODE_MAX / 128:g} degC)")
        win_lo, win_hi = _training_window(ch, lo, hi)
        step, source = _channel_step(ch, period_s)
        out.append(QChannel(ch.channel, ch.sensor, ch.tc_type, TC_TYPES[ch.tc_type], ch.min_c,
                            ch.max_c, lo, hi, win_lo, win_hi, step, source,
                            ch.max_still_samples or 0))
    return tuple(out)


def _training_window(ch: ChannelSpec, lo: int, hi: int) -> tuple[int, int]:
    """Codes outside which a valid reading is an extrapolation: the training range
    (``trained_min_c``..``trained_max_c``) widened by EXTRAPOLATION_MARGIN of its span on each
    side, rounded outwards and kept inside the valid range. Without a training range: the
    valid range (the box never flags)."""
    if ch.trained_min_c is None or ch.trained_max_c is None:
        return lo, hi
    t_lo, t_hi = Fraction(ch.trained_min_c), Fraction(ch.trained_max_c)
    margin = (t_hi - t_lo) * EXTRAPOLATION_MARGIN
    w_lo = math.floor((t_lo - margin) * 128)
    w_hi = math.ceil((t_hi + margin) * 128)
    return min(max(w_lo, lo), hi), max(min(w_hi, hi), lo)


def _channel_step(ch: ChannelSpec, period_s: float) -> tuple[int, str]:
    """The largest plausible change of the channel per sample, in codes: ``max_step_c``
    (host train: the training runs' fastest change with a margin) rounded up to whole codes;
    a model.json without it gets the conservative default max(1 degC, 0.1 degC/s x period)."""
    if ch.max_step_c is not None:
        step_c = Fraction(ch.max_step_c)
        source = "model"
    else:
        # the documented decimal rates, exactly (Fraction(0.1) is 0.1000000000000000055...)
        step_c = max(Fraction(str(DEFAULT_CHANNEL_STEP_MIN_C)),
                     Fraction(str(DEFAULT_CHANNEL_STEP_C_PER_S)) * Fraction(period_s))
        source = "default"
    code = math.ceil(step_c * (1 << TEMP_FRAC_BITS))
    return max(1, min(code, CODE_MAX - CODE_MIN)), source


def parse_aux(aux: Sequence[AuxSpec]) -> tuple[QAux, ...]:
    """The aux inputs' integer ranges (the box reads whole units)."""
    out = []
    for a in aux:
        lo, hi = math.ceil(a.min), math.floor(a.max)
        if not INT32_MIN <= lo <= hi <= INT32_MAX:
            raise CodegenError(f"aux[{a.input}] ({a.name}): range {a.min:g}..{a.max:g} must be "
                               f"non-empty and within int32 ({INT32_MIN}..{INT32_MAX})")
        out.append(QAux(a.input, a.name, a.min, a.max, lo, hi))
    return tuple(out)


def parse_period(period_s: float) -> int:
    """The sample period in whole milliseconds (the box's timer)."""
    ms = Fraction(period_s) * 1000
    period_ms = round(ms)
    if period_s <= 0 or abs(ms - period_ms) > Fraction(1, 10**6) * max(1, period_ms) \
            or not 1 <= period_ms <= UINT32_MAX:
        raise CodegenError(f"sample_period_s: {period_s!r} s must be a whole number of "
                           f"milliseconds between 1 ms and {UINT32_MAX} ms (the box's timer)")
    return period_ms

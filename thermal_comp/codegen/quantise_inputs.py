"""Quantising the model's inputs: the sample period, the channels' codes, the aux ranges.

Each check guards the number quantised beside it (docs/fixed-point.md): a valid range must give
codes inside the chip's 19 bits, a period whole milliseconds, and so on; the messages name the
key and the limit like contract.model_file's.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from fractions import Fraction

from thermal_comp.codegen.errors import CodegenError
from thermal_comp.codegen.qmodel import (
    DEFAULT_MAX_C,
    DEFAULT_MIN_C,
    MAX_AUX,
    MAX_CHANNELS,
    QAux,
    QChannel,
)
from thermal_comp.contract.box import (
    DEFAULT_CHANNEL_STEP_C_PER_S,
    DEFAULT_CHANNEL_STEP_MIN_C,
    MAX_STILL_SAMPLES,
    MIN_STILL_SAMPLES,
)
from thermal_comp.contract.fixed_point import (
    CODE_MAX,
    CODE_MIN,
    EXTRAPOLATION_MARGIN,
    INT32_MAX,
    INT32_MIN,
    TEMP_FRAC_BITS,
    UINT32_MAX,
)
from thermal_comp.contract.model_file import NAME_RE
from thermal_comp.contract.terms import TC_TYPES


def number(value: object, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise CodegenError(f"{where}: expected a number, got {value!r}")
    if not math.isfinite(value):
        raise CodegenError(f"{where}: expected a finite number, got {value!r}")
    return float(value)


def check_name(value: object, where: str) -> str:
    if not isinstance(value, str) or not NAME_RE.match(value):
        raise CodegenError(f"{where}: name {value!r} must be 1-32 characters of "
                           "A-Z a-z 0-9 _ . + - (it goes into C strings and the INFO line)")
    return value


def _index_list(items: Sequence[Mapping], key: str, what: str) -> list[Mapping]:
    """Items sorted by their index field, which must be exactly 0..n-1."""
    indices = []
    for i, item in enumerate(items):
        v = item.get(key)
        if isinstance(v, bool) or not isinstance(v, int):
            raise CodegenError(f"{what}[{i}].{key}: expected an integer index, got {v!r}")
        indices.append(v)
    if sorted(indices) != list(range(len(items))):
        raise CodegenError(f"{what}: the {key} indices must be 0..{len(items) - 1} "
                           f"(one per entry), got {sorted(indices)}")
    return [items[indices.index(i)] for i in range(len(items))]


def parse_channels(model: Mapping, period_s: float) -> tuple[QChannel, ...]:
    raw = model.get("channels", [])
    if not isinstance(raw, list):
        raise CodegenError("channels: expected a list")
    if len(raw) > MAX_CHANNELS:
        raise CodegenError(f"channels: {len(raw)} channels exceed the runtime's "
                           f"{MAX_CHANNELS} (TCM_MAX_CHANNELS)")
    out = []
    for ch in _index_list(raw, "channel", "channels"):
        i = ch["channel"]
        where = f"channels[{i}]"
        sensor = check_name(ch.get("sensor"), f"{where}.sensor")
        tc = ch.get("tc_type", "K")
        if tc not in TC_TYPES:
            raise CodegenError(f"{where} ({sensor}): thermocouple type {tc!r} is not "
                               f"supported (known: {', '.join(TC_TYPES)})")
        min_c = number(ch.get("min_c", DEFAULT_MIN_C), f"{where}.min_c")
        max_c = number(ch.get("max_c", DEFAULT_MAX_C), f"{where}.max_c")
        lo = math.ceil(Fraction(min_c) * 128)
        hi = math.floor(Fraction(max_c) * 128)
        if not CODE_MIN <= lo <= hi <= CODE_MAX:
            raise CodegenError(
                f"{where} ({sensor}): valid range {min_c:g}..{max_c:g} degC gives codes "
                f"{lo}..{hi}; it must be non-empty and inside the chip's 19-bit range "
                f"{CODE_MIN}..{CODE_MAX} ({CODE_MIN / 128:g}..{CODE_MAX / 128:g} degC)")
        win_lo, win_hi = _training_window(ch, where, sensor, lo, hi)
        step, source = _channel_step(ch, where, sensor, period_s)
        out.append(QChannel(i, sensor, tc, TC_TYPES[tc], min_c, max_c, lo, hi, win_lo, win_hi,
                            step, source, _channel_still(ch, where, sensor)))
    if len({c.sensor for c in out}) != len(out):
        raise CodegenError("channels: sensor names must be unique")
    return tuple(out)


def _training_window(ch: Mapping, where: str, sensor: str, lo: int, hi: int
                     ) -> tuple[int, int]:
    """Codes outside which a valid reading is an extrapolation: the training range
    (``trained_min_c``..``trained_max_c``) widened by EXTRAPOLATION_MARGIN of its span on each
    side, rounded outwards and kept inside the valid range. Without a training range: the
    valid range (the box never flags)."""
    if "trained_min_c" not in ch and "trained_max_c" not in ch:
        return lo, hi
    t_lo = number(ch.get("trained_min_c"), f"{where}.trained_min_c")
    t_hi = number(ch.get("trained_max_c"), f"{where}.trained_max_c")
    if t_lo > t_hi:
        raise CodegenError(f"{where} ({sensor}): training range {t_lo:g}..{t_hi:g} degC is "
                           "empty (trained_min_c > trained_max_c)")
    margin = (Fraction(t_hi) - Fraction(t_lo)) * EXTRAPOLATION_MARGIN
    w_lo = math.floor((Fraction(t_lo) - margin) * 128)
    w_hi = math.ceil((Fraction(t_hi) + margin) * 128)
    return min(max(w_lo, lo), hi), max(min(w_hi, hi), lo)


def _channel_step(ch: Mapping, where: str, sensor: str, period_s: float) -> tuple[int, str]:
    """The largest plausible change of the channel per sample, in codes: ``max_step_c``
    (host train: the training runs' fastest change with a margin) rounded up to whole codes;
    a model.json without it gets the conservative default max(1 degC, 0.1 degC/s x period)."""
    if "max_step_c" in ch:
        step_c = Fraction(number(ch.get("max_step_c"), f"{where}.max_step_c"))
        source = "model"
        if step_c <= 0:
            raise CodegenError(f"{where} ({sensor}): max_step_c {float(step_c)!r} degC must be "
                               "positive (the largest plausible change per sample)")
    else:
        # the documented decimal rates, exactly (Fraction(0.1) is 0.1000000000000000055...)
        step_c = max(Fraction(str(DEFAULT_CHANNEL_STEP_MIN_C)),
                     Fraction(str(DEFAULT_CHANNEL_STEP_C_PER_S)) * Fraction(period_s))
        source = "default"
    code = math.ceil(step_c * (1 << TEMP_FRAC_BITS))
    return max(1, min(code, CODE_MAX - CODE_MIN)), source


def _channel_still(ch: Mapping, where: str, sensor: str) -> int:
    """The stuck limit: ``max_still_samples`` (host train: twice the longest run of one code
    in training, at least 10), or 0 (no stuck check) for a model.json without it."""
    if "max_still_samples" not in ch:
        return 0
    v = ch["max_still_samples"]
    if isinstance(v, bool) or not isinstance(v, int) \
            or not MIN_STILL_SAMPLES <= v <= MAX_STILL_SAMPLES:
        raise CodegenError(f"{where}.max_still_samples ({sensor}): {v!r} must be a whole "
                           f"number of samples from {MIN_STILL_SAMPLES} to {MAX_STILL_SAMPLES}")
    return v


def parse_aux(model: Mapping) -> tuple[QAux, ...]:
    raw = model.get("aux", [])
    if not isinstance(raw, list):
        raise CodegenError("aux: expected a list")
    if len(raw) > MAX_AUX:
        raise CodegenError(f"aux: {len(raw)} inputs exceed the runtime's {MAX_AUX} "
                           "(TCM_MAX_AUX)")
    out = []
    for ax in _index_list(raw, "input", "aux"):
        i = ax["input"]
        where = f"aux[{i}]"
        name = check_name(ax.get("name"), f"{where}.name")
        lo_v = number(ax.get("min"), f"{where}.min")
        hi_v = number(ax.get("max"), f"{where}.max")
        lo, hi = math.ceil(lo_v), math.floor(hi_v)
        if not INT32_MIN <= lo <= hi <= INT32_MAX:
            raise CodegenError(f"{where} ({name}): range {lo_v:g}..{hi_v:g} must be non-empty "
                               f"and within int32 ({INT32_MIN}..{INT32_MAX})")
        out.append(QAux(i, name, lo_v, hi_v, lo, hi))
    if len({a.name for a in out}) != len(out):
        raise CodegenError("aux: names must be unique")
    return tuple(out)


def parse_period(model: Mapping) -> tuple[float, int]:
    period_s = number(model.get("sample_period_s"), "sample_period_s")
    ms = Fraction(period_s) * 1000
    period_ms = round(ms)
    if period_s <= 0 or abs(ms - period_ms) > Fraction(1, 10**6) * max(1, period_ms) \
            or not 1 <= period_ms <= UINT32_MAX:
        raise CodegenError(f"sample_period_s: {period_s!r} s must be a whole number of "
                           f"milliseconds between 1 ms and {UINT32_MAX} ms (the box's timer)")
    return period_s, period_ms

"""Stage 1 of codegen: model.json dict -> validated, already-quantised ``QModel``.

Over 400 lines as one stage on purpose: validating model.json and quantising it are one pass
(each check guards a number that is quantised next to it), in the order of docs/fixed-point.md.

Everything numeric the header, the CRC, the error bound and the Python twin need is decided
here, in exact rational arithmetic (``fractions.Fraction``), so that rendering is pure
formatting and the twin evaluates exactly the tables the firmware gets. The rules are
docs/fixed-point.md; the choices it leaves open are docs/codegen.md.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from fractions import Fraction

from thermal_comp.codegen.errors import CodegenError
from thermal_comp.codegen.estimator import FixedParams
from thermal_comp.contract.box import (
    CHANNEL_MAX_C,
    CHANNEL_MIN_C,
    DEFAULT_AXIS_STEP_UM_PER_S,
    DEFAULT_CHANNEL_STEP_C_PER_S,
    DEFAULT_CHANNEL_STEP_MIN_C,
    MAX_STILL_SAMPLES,
    MIN_STILL_SAMPLES,
    RUNTIME_MAX_AUX,
    RUNTIME_MAX_AXES,
    RUNTIME_MAX_CHANNELS,
    RUNTIME_MAX_STATES,
    RUNTIME_MAX_TERMS_PER_AXIS,
)
from thermal_comp.contract.fixed_point import (
    ACC_LIMIT,
    ALPHA_FRAC_BITS,
    CODE_MAX,
    CODE_MIN,
    EXTRAPOLATION_MARGIN,
    INT32_MAX,
    INT32_MIN,
    MAX_SHIFT,
    STATE_FRAC_BITS,
    TEMP_FRAC_BITS,
    UINT32_MAX,
    rdiv,
    round_half_away,
)
from thermal_comp.contract.model_file import NAME_RE, SCHEMA, ModelFormatError, check_model
from thermal_comp.contract.service import SERVICE_FIELDS, SERVICE_OPTIONAL
from thermal_comp.contract.terms import (
    AUX_KINDS,
    FILTER_KINDS,
    KIND_CODES,
    TC_TYPES,
    TEMPERATURE_KINDS,
)
from thermal_comp.contract.tilt import AXIS_UNITS

# Runtime capacity (firmware/include/model_eval.h), named as codegen's messages use them.
MAX_CHANNELS = RUNTIME_MAX_CHANNELS
MAX_AUX = RUNTIME_MAX_AUX
MAX_AXES = RUNTIME_MAX_AXES
MAX_STATES = RUNTIME_MAX_STATES
MAX_TERMS_PER_AXIS = RUNTIME_MAX_TERMS_PER_AXIS
DEFAULT_MIN_C = CHANNEL_MIN_C
DEFAULT_MAX_C = CHANNEL_MAX_C

# Names end up in C string literals, comments and the wire protocol's INFO line: the
# contract's NAME_RE (contract/model_file.py) says which characters are safe in all three.

# Value of one unit of x_j in the unit the coefficient is per (degC, degC^2, rpm, rpm^2, s);
# `time` uses the sample period and is filled in per model.
_X_UNIT = {
    "temp": Fraction(1, 1 << TEMP_FRAC_BITS),
    "lag": Fraction(1, 1 << (TEMP_FRAC_BITS + STATE_FRAC_BITS)),
    "rate": Fraction(1, 1 << (TEMP_FRAC_BITS + STATE_FRAC_BITS)),
    "speed": Fraction(1),
    "speed2": Fraction(1),
    "square": Fraction(1, 1 << (2 * TEMP_FRAC_BITS)),
}
COEF_UNIT = {"temp": "um/degC", "lag": "um/degC", "rate": "um/degC", "speed": "um/rpm",
             "speed2": "um/rpm^2", "square": "um/degC^2", "time": "um/s"}
X_UNIT_TEXT = {"temp": "1/128 degC", "lag": "2^-23 degC", "rate": "2^-23 degC",
               "speed": "rpm", "speed2": "rpm^2", "square": "2^-14 degC^2",
               "time": "sample periods"}


@dataclass(frozen=True)
class QChannel:
    index: int
    sensor: str
    tc_type: str
    tc_code: int
    min_c: float
    max_c: float
    min_code: int
    max_code: int
    window_lo_code: int  # training range widened by EXTRAPOLATION_MARGIN, in codes; the
    window_hi_code: int  # valid range when the model has no training range for the channel
    max_step_code: int = 1  # largest plausible change per sample (codes, >= 1): IMPLAUSIBLE
    max_step_source: str = "model"  # "model" (max_step_c) or "default" (older model.json)
    max_still_samples: int = 0  # same code this many samples in a row: STUCK (0: no check)


@dataclass(frozen=True)
class QAux:
    index: int
    name: str
    min_value: float
    max_value: float
    min: int
    max: int


@dataclass(frozen=True)
class QTerm:
    """One quantised term. ``c`` is the exact real coefficient in nm per unit of x_j."""

    position: int  # index within its axis
    kind: str
    kind_code: int
    source: str | None
    input: int  # channel or aux index (0 for time)
    param: int  # a, ref_code, time_max_samples or 0
    state: int | None  # filter state index (lag/rate; shared by equal input and a)
    coef_um: float
    c: Fraction
    coef_q: int
    xmax: int  # max |x_j| over the declared input ranges
    label: str
    params: Mapping[str, float]

    @property
    def coef_unit(self) -> str:
        return COEF_UNIT[self.kind]


@dataclass(frozen=True)
class QAxis:
    index: int
    name: str
    unit: str
    intercept_um: float
    c0: Fraction  # exact intercept in nm
    shift: int
    intercept_q: int
    terms: tuple[QTerm, ...]
    acc_max: int  # |intercept_q| + sum |coef_q| * max(xmax, 1)
    out_max_nm: int  # rdiv(acc_max, shift)
    max_step_nm: int = 1  # the output never steps more than this per sample (nm, >= 1)
    max_step_source: str = "model"  # "model" (max_step_um) or "default" (older model.json)
    # the in-service estimator's parameters (codegen.estimator.FixedParams) from the axis's
    # service block; None: the model has none and the box refuses MEAS for the axis (OFF)
    service: FixedParams | None = None


@dataclass(frozen=True)
class QModel:
    schema: str
    model_hash: str
    period_s: float
    period_ms: int
    time_max_s: float | None
    time_max_samples: int | None
    channels: tuple[QChannel, ...]
    aux: tuple[QAux, ...]
    axes: tuple[QAxis, ...]

    @property
    def n_terms(self) -> int:
        return sum(len(ax.terms) for ax in self.axes)

    @property
    def n_states(self) -> int:
        """Distinct filter states: lags and rates of one channel with one a share one."""
        return len({t.state for ax in self.axes for t in ax.terms if t.kind in FILTER_KINDS})

    def all_terms(self) -> list[QTerm]:
        return [t for ax in self.axes for t in ax.terms]


# ---- validation helpers --------------------------------------------------------------------

def _number(value: object, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise CodegenError(f"{where}: expected a number, got {value!r}")
    if not math.isfinite(value):
        raise CodegenError(f"{where}: expected a finite number, got {value!r}")
    return float(value)


def _name(value: object, where: str) -> str:
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


def _parse_channels(model: Mapping, period_s: float) -> tuple[QChannel, ...]:
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
        sensor = _name(ch.get("sensor"), f"{where}.sensor")
        tc = ch.get("tc_type", "K")
        if tc not in TC_TYPES:
            raise CodegenError(f"{where} ({sensor}): thermocouple type {tc!r} is not "
                               f"supported (known: {', '.join(TC_TYPES)})")
        min_c = _number(ch.get("min_c", DEFAULT_MIN_C), f"{where}.min_c")
        max_c = _number(ch.get("max_c", DEFAULT_MAX_C), f"{where}.max_c")
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
    t_lo = _number(ch.get("trained_min_c"), f"{where}.trained_min_c")
    t_hi = _number(ch.get("trained_max_c"), f"{where}.trained_max_c")
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
        step_c = Fraction(_number(ch.get("max_step_c"), f"{where}.max_step_c"))
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


def _axis_step(ax: Mapping, name: str, period_s: float) -> tuple[int, str]:
    """The largest output step per sample, in nm: ``max_step_um`` (host train: the training
    runs' fastest change of the model output with a margin) rounded up; a model.json without
    it gets the box's walk-back rate, 1 um/s x period."""
    if "max_step_um" in ax:
        step_um = Fraction(_number(ax.get("max_step_um"), f"axis '{name}': max_step_um"))
        source = "model"
        if step_um <= 0:
            raise CodegenError(f"axis '{name}': max_step_um {float(step_um)!r} um must be "
                               "positive (the largest output step per sample)")
    else:
        step_um = Fraction(str(DEFAULT_AXIS_STEP_UM_PER_S)) * Fraction(period_s)
        source = "default"
    return max(1, min(math.ceil(step_um * 1000), INT32_MAX)), source


def _parse_aux(model: Mapping) -> tuple[QAux, ...]:
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
        name = _name(ax.get("name"), f"{where}.name")
        lo_v = _number(ax.get("min"), f"{where}.min")
        hi_v = _number(ax.get("max"), f"{where}.max")
        lo, hi = math.ceil(lo_v), math.floor(hi_v)
        if not INT32_MIN <= lo <= hi <= INT32_MAX:
            raise CodegenError(f"{where} ({name}): range {lo_v:g}..{hi_v:g} must be non-empty "
                               f"and within int32 ({INT32_MIN}..{INT32_MAX})")
        out.append(QAux(i, name, lo_v, hi_v, lo, hi))
    if len({a.name for a in out}) != len(out):
        raise CodegenError("aux: names must be unique")
    return tuple(out)


def _period(model: Mapping) -> tuple[float, int]:
    period_s = _number(model.get("sample_period_s"), "sample_period_s")
    ms = Fraction(period_s) * 1000
    period_ms = round(ms)
    if period_s <= 0 or abs(ms - period_ms) > Fraction(1, 10**6) * max(1, period_ms) \
            or not 1 <= period_ms <= UINT32_MAX:
        raise CodegenError(f"sample_period_s: {period_s!r} s must be a whole number of "
                           f"milliseconds between 1 ms and {UINT32_MAX} ms (the box's timer)")
    return period_s, period_ms


def _label(kind: str, source: str | None, t: Mapping) -> str:
    if kind in FILTER_KINDS:
        tau = t.get("tau_s")
        return f"{kind}({source}, tau={tau:g}s)" if isinstance(tau, (int, float)) \
            else f"{kind}({source})"
    if kind == "square":
        ref = t.get("ref_c")
        return f"square({source}-{ref:g}C)" if isinstance(ref, (int, float)) \
            else f"square({source})"
    if kind == "time":
        return "time"
    return f"{kind}({source})"


def _xmax(kind: str, lo: int, hi: int, param: int) -> int:
    """max |x_j| over [lo, hi] (proofs in docs/codegen.md; same as TCM_XMAX_* in C)."""
    m = max(abs(lo), abs(hi))
    if kind in ("temp", "speed"):
        return m
    if kind == "lag":
        return m << STATE_FRAC_BITS
    if kind == "rate":
        return (hi - lo) << STATE_FRAC_BITS
    if kind == "speed2":
        return m * m
    if kind == "square":
        e = max(abs(lo - param), abs(hi - param))
        return e * e
    if kind == "time":
        return param
    raise AssertionError(kind)


@dataclass(frozen=True)
class _RawTerm:
    position: int
    kind: str
    source: str | None
    input: int
    param: int
    coef_um: float
    c: Fraction
    xmax: int
    label: str
    params: Mapping[str, float]


def _parse_term(axis: str, j: int, t: Mapping, channels: Sequence[QChannel],
                aux: Sequence[QAux], period_s: float, time_max_samples: int | None) -> _RawTerm:
    where = f"axis '{axis}' term {j}"
    if not isinstance(t, Mapping):
        raise CodegenError(f"{where}: expected an object")
    kind = t.get("kind")
    if kind not in KIND_CODES:
        raise CodegenError(f"{where}: unknown term kind {kind!r} "
                           f"(known: {', '.join(KIND_CODES)})")
    source = t.get("source")
    label = _label(kind, source, t)
    where = f"{where} {label}"
    coef = _number(t.get("coef"), f"{where}: coef")
    params = {k: float(v) for k, v in t.items()
              if k not in ("kind", "source", "coef") and isinstance(v, (int, float))}
    index, lo, hi, param = _term_input(kind, source, where, channels, aux, time_max_samples)
    param = _term_param(kind, t, where, lo, hi, param)
    unit = Fraction(period_s) if kind == "time" else _X_UNIT[kind]
    c = Fraction(coef) * 1000 * unit
    return _RawTerm(j, kind, source, index, param, coef, c, _xmax(kind, lo, hi, param),
                    label, params)


def _term_input(kind: str, source: object, where: str, channels: Sequence[QChannel],
                aux: Sequence[QAux], time_max_samples: int | None
                ) -> tuple[int, int, int, int]:
    """(input index, lowest and highest input value, time's parameter) of a term's source."""
    param = 0
    if kind in TEMPERATURE_KINDS:
        by_name = {c.sensor: c for c in channels}
        if source not in by_name:
            raise CodegenError(f"{where}: source {source!r} is not in channels "
                               f"({', '.join(by_name) or 'none'})")
        ch = by_name[source]
        index, lo, hi = ch.index, ch.min_code, ch.max_code
    elif kind in AUX_KINDS:
        by_name = {a.name: a for a in aux}
        if source not in by_name:
            raise CodegenError(f"{where}: source {source!r} is not in aux "
                               f"({', '.join(by_name) or 'none'})")
        ax = by_name[source]
        index, lo, hi = ax.index, ax.min, ax.max
    else:  # time
        if source is not None:
            raise CodegenError(f"{where}: a time term has no source (got {source!r})")
        if time_max_samples is None:
            raise CodegenError(f"{where}: the model needs time_max_s for a time term")
        index, lo, hi = 0, 0, 0
        param = time_max_samples
    return index, lo, hi, param


def _term_param(kind: str, t: Mapping, where: str, lo: int, hi: int, param: int) -> int:
    """The term's integer parameter: a filter's alpha in 2^-30, a square's reference code."""
    if kind in FILTER_KINDS:
        alpha = _number(t.get("alpha"), f"{where}: alpha")
        a = Fraction(alpha) * (1 << ALPHA_FRAC_BITS)
        if a.denominator != 1 or not 1 <= a <= (1 << ALPHA_FRAC_BITS):
            raise CodegenError(f"{where}: alpha {alpha!r} must be a multiple of 2^-30 in "
                               "(0, 1] (make it with contract.terms.make_lag/make_rate)")
        param = int(a)
        product = (hi - lo) * (1 << STATE_FRAC_BITS) * param
        if product > ACC_LIMIT:
            raise CodegenError(
                f"{where}: filter update |d*a| can reach {product} > 2^62 = {ACC_LIMIT} "
                f"(channel range {lo}..{hi} codes, a = {param}); narrow the channel's "
                "declared range or use a longer tau")
    elif kind == "square":
        ref_c = _number(t.get("ref_c"), f"{where}: ref_c")
        ref = Fraction(ref_c) * 128
        if ref.denominator != 1 or not CODE_MIN <= ref <= CODE_MAX:
            raise CodegenError(f"{where}: ref_c {ref_c!r} must be a multiple of 1/128 degC "
                               f"within {CODE_MIN / 128:g}..{CODE_MAX / 128:g} degC "
                               "(make it with contract.terms.make_square)")
        param = int(ref)
    return param


def _choose_shift(axis: str, c0: Fraction, raw: Sequence[_RawTerm]) -> tuple[int, int,
                                                                              list[int], int]:
    """Largest F in 0..62 with |intercept_q| + sum |coef_q| * max(xmax, 1) <= 2^62."""
    for f in range(MAX_SHIFT, -1, -1):
        scale = 1 << f
        iq = round_half_away(c0 * scale)
        cqs = [round_half_away(t.c * scale) for t in raw]
        acc = abs(iq) + sum(abs(q) * max(t.xmax, 1) for q, t in zip(cqs, raw, strict=True))
        if acc <= ACC_LIMIT:
            return f, iq, cqs, acc
    # Not even F = 0 fits: name the biggest contributor.
    parts = [(abs(round_half_away(c0)), "intercept", None)] + [
        (abs(round_half_away(t.c)) * max(t.xmax, 1), f"term {t.position} {t.label}", t)
        for t in raw]
    value, what, term = max(parts, key=lambda p: p[0])
    if term is None:
        raise CodegenError(f"axis '{axis}': intercept {float(c0) / 1000!r} um cannot be "
                           f"represented: {value} nm exceeds the accumulator limit 2^62")
    raise CodegenError(
        f"axis '{axis}': {what} coefficient {term.coef_um!r} {COEF_UNIT[term.kind]} cannot be "
        f"represented: |coef_q|*max|x| = {value} exceeds the accumulator limit 2^62 = "
        f"{ACC_LIMIT} even at shift 0 (max |x| = {term.xmax} x {X_UNIT_TEXT[term.kind]})")


def _parse_axis(index: int, name: str, ax: Mapping, channels: Sequence[QChannel],
                aux: Sequence[QAux], period_s: float,
                time_max_samples: int | None) -> QAxis:
    _name(name, f"axes.{name}")
    if not isinstance(ax, Mapping):
        raise CodegenError(f"axis '{name}': expected an object")
    unit = ax.get("unit", "um")
    if unit not in AXIS_UNITS:  # a tilt axis (urad) is computed like any: in thousandths
        raise CodegenError(f"axis '{name}': unit {unit!r} is not supported (one of "
                           f"{', '.join(AXIS_UNITS)})")
    intercept = _number(ax.get("intercept"), f"axis '{name}': intercept")
    terms = ax.get("terms", [])
    if not isinstance(terms, list):
        raise CodegenError(f"axis '{name}': terms must be a list")
    if len(terms) > MAX_TERMS_PER_AXIS:
        raise CodegenError(f"axis '{name}': {len(terms)} terms exceed {MAX_TERMS_PER_AXIS}")
    raw = [_parse_term(name, j, t, channels, aux, period_s, time_max_samples)
           for j, t in enumerate(terms)]
    c0 = Fraction(intercept) * 1000
    shift, iq, cqs, acc = _choose_shift(name, c0, raw)
    out_max = rdiv(acc, shift)
    if out_max > INT32_MAX:
        biggest = max(raw, key=lambda t: abs(t.c) * t.xmax, default=None)
        part = (f"; largest part: term {biggest.position} {biggest.label}, coef "
                f"{biggest.coef_um!r} {COEF_UNIT[biggest.kind]}, up to "
                f"{float(abs(biggest.c) * biggest.xmax) / 1000:.6g} um" if biggest else "")
        raise CodegenError(
            f"axis '{name}': the output can reach {out_max / 1000:.6g} um over the declared "
            f"input ranges, beyond the int32 nanometre limit {INT32_MAX / 1000:.6g} um{part}")
    step, source = _axis_step(ax, name, period_s)
    return QAxis(index, name, unit, intercept, c0, shift, iq, tuple(
        QTerm(t.position, t.kind, KIND_CODES[t.kind], t.source, t.input, t.param, None,
              t.coef_um, t.c, q, t.xmax, t.label, t.params)
        for t, q in zip(raw, cqs, strict=True)), acc, out_max, step, source)


def _number_states(axes: list[QAxis]) -> tuple[QAxis, ...]:
    """A filter term's state index: the rank of its (channel, a) among the distinct ones in
    table order. The lags and rates of one sensor with one time constant share a state
    (rate = T - lag), on any axis, so the box updates it once per sample."""
    out, index = [], {}
    for ax in axes:
        terms = []
        for t in ax.terms:
            if t.kind in FILTER_KINDS:
                state = index.setdefault((t.input, t.param), len(index))
                terms.append(QTerm(**{**t.__dict__, "state": state}))
            else:
                terms.append(t)
        out.append(QAxis(**{**ax.__dict__, "terms": tuple(terms)}))
    if len(index) > MAX_STATES:
        raise CodegenError(f"the model has {len(index)} distinct lag/rate filters (sensor and "
                           f"time constant); the runtime holds {MAX_STATES} filter states "
                           "(TCM_MAX_STATES)")
    return tuple(out)


def quantise(model: Mapping) -> QModel:
    """Validate a model.json dict and quantise it (raises CodegenError naming the problem).

    The structural checks are ``contract.model_file.check_model``'s (the same for every
    command); what follows adds only what needs the fixed-point encoding.
    """
    from thermal_comp.codegen.hashing import model_hash

    try:  # the structural rules every command shares (contract.model_file)
        check_model(model, "", output_range=False)
    except ModelFormatError as exc:
        raise CodegenError(str(exc)) from None
    schema = model.get("schema")
    if schema != SCHEMA:
        raise CodegenError(f"schema {schema!r} is not supported (expected {SCHEMA!r})")
    period_s, period_ms = _period(model)
    channels = _parse_channels(model, period_s)
    aux = _parse_aux(model)
    time_max_s = model.get("time_max_s")
    time_max_samples = None
    if time_max_s is not None:
        time_max_s = _number(time_max_s, "time_max_s")
        time_max_samples = math.floor(Fraction(time_max_s) / Fraction(period_s))
        if not 0 <= time_max_samples <= INT32_MAX:
            raise CodegenError(f"time_max_s: {time_max_s!r} s is {time_max_samples} samples; "
                               f"it must be within 0..{INT32_MAX} samples")
    axes_raw = model.get("axes")
    if not isinstance(axes_raw, Mapping) or not axes_raw:
        raise CodegenError("axes: the model has no axes")
    if len(axes_raw) > MAX_AXES:
        raise CodegenError(f"axes: {len(axes_raw)} axes exceed the runtime's {MAX_AXES}")
    axes = [_parse_axis(i, name, ax, channels, aux, period_s, time_max_samples)
            for i, (name, ax) in enumerate(axes_raw.items())]
    start = (model.get("reference") or {}).get("kind", "none") == "start"
    axes = [_with_service(ax, axes_raw[ax.name], period_s, start) for ax in axes]
    return QModel(SCHEMA, model_hash(model), period_s, period_ms, time_max_s,
                  time_max_samples, channels, aux, _number_states(axes))


def _with_service(ax: QAxis, raw: Mapping, period_s: float, start: bool) -> QAxis:
    """The axis with its estimator parameters quantised (docs/service.md, "Fixed point"),
    when model.json has a ``service`` block for it."""
    block = raw.get("service")
    if block is None:
        return ax
    try:
        block = dict(SERVICE_OPTIONAL) | dict(block)
        params = FixedParams.of(**{k: float(block[k]) for k in SERVICE_FIELDS},
                                period_s=period_s, start=start)
    except CodegenError as exc:
        raise CodegenError(f"axis '{ax.name}': {exc}") from None
    return QAxis(**{**ax.__dict__, "service": params})

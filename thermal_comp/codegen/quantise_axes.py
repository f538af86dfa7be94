"""Quantising an axis: its terms' coefficients and inputs, the shared shift, the step limit,
the filter states and the in-service estimator's parameters.

The shift is the largest that keeps the accumulator within 2^62 over the declared input ranges
(docs/codegen.md), so the box can never overflow; a coefficient that cannot fit is refused,
naming the term.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from fractions import Fraction

from thermal_comp.codegen.errors import CodegenError
from thermal_comp.codegen.estimator import FixedParams
from thermal_comp.codegen.qmodel import (
    COEF_UNIT,
    MAX_STATES,
    X_UNIT_TEXT,
    QAux,
    QAxis,
    QChannel,
    QTerm,
)
from thermal_comp.contract.box import DEFAULT_AXIS_STEP_UM_PER_S
from thermal_comp.contract.fixed_point import (
    ACC_LIMIT,
    ALPHA_FRAC_BITS,
    CODE_MAX,
    CODE_MIN,
    INT32_MAX,
    MAX_SHIFT,
    STATE_FRAC_BITS,
    TEMP_FRAC_BITS,
    rdiv,
    round_half_away,
)
from thermal_comp.contract.model_spec import AxisSpec, ServiceSpec
from thermal_comp.contract.terms import (
    AUX_KINDS,
    FILTER_KINDS,
    KIND_CODES,
    TEMPERATURE_KINDS,
    Term,
)

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


def _label(term: Term) -> str:
    kind, source, p = term.kind, term.source, term.params
    if kind in FILTER_KINDS:
        return f"{kind}({source}, tau={p['tau_s']:g}s)"
    if kind == "square":
        return f"square({source}-{p['ref_c']:g}C)"
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


def _parse_term(axis: str, j: int, term: Term, coef: float, channels: Sequence[QChannel],
                aux: Sequence[QAux], period_s: float, time_max_samples: int | None) -> _RawTerm:
    """Term ``j`` of ``axis`` (checked by contract.model_axis) in the box's integers."""
    kind = term.kind
    label = _label(term)
    where = f"axis '{axis}' term {j} {label}"
    index, lo, hi, param = _term_input(term, channels, aux, time_max_samples)
    param = _term_param(term, where, lo, hi, param)
    unit = Fraction(period_s) if kind == "time" else _X_UNIT[kind]
    c = Fraction(coef) * 1000 * unit
    return _RawTerm(j, kind, term.source, index, param, coef, c, _xmax(kind, lo, hi, param),
                    label, term.params)


def _term_input(term: Term, channels: Sequence[QChannel], aux: Sequence[QAux],
                time_max_samples: int | None) -> tuple[int, int, int, int]:
    """(input index, lowest and highest input value, time's parameter) of a term's source
    (wired to a channel or aux input of the model: contract.model_axis checked it)."""
    if term.kind in TEMPERATURE_KINDS:
        ch = next(c for c in channels if c.sensor == term.source)
        return ch.index, ch.min_code, ch.max_code, 0
    if term.kind in AUX_KINDS:
        a = next(a for a in aux if a.name == term.source)
        return a.index, a.min, a.max, 0
    assert time_max_samples is not None  # a time term needs time_max_s (check_model)
    return 0, 0, 0, time_max_samples


def _term_param(term: Term, where: str, lo: int, hi: int, param: int) -> int:
    """The term's integer parameter: a filter's alpha in 2^-30, a square's reference code."""
    kind = term.kind
    if kind in FILTER_KINDS:
        alpha = term.params["alpha"]
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
        ref_c = term.params["ref_c"]
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


def parse_axis(index: int, ax: AxisSpec, channels: Sequence[QChannel], aux: Sequence[QAux],
               period_s: float, time_max_samples: int | None) -> QAxis:
    """Axis ``ax`` (checked by contract.model_axis; a tilt axis in urad is computed like any,
    in thousandths) in the box's integers: shift, coefficients, output and step limits."""
    name, intercept = ax.name, ax.intercept
    raw = [_parse_term(name, j, t, coef, channels, aux, period_s, time_max_samples)
           for j, (t, coef) in enumerate(zip(ax.terms, ax.coefs, strict=True))]
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
    step, source = _axis_step(ax, period_s)
    return QAxis(index, name, ax.unit, intercept, c0, shift, iq, tuple(
        QTerm(t.position, t.kind, KIND_CODES[t.kind], t.source, t.input, t.param, None,
              t.coef_um, t.c, q, t.xmax, t.label, t.params)
        for t, q in zip(raw, cqs, strict=True)), acc, out_max, step, source)


def number_states(axes: list[QAxis]) -> tuple[QAxis, ...]:
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


def _axis_step(ax: AxisSpec, period_s: float) -> tuple[int, str]:
    """The largest output step per sample, in nm: ``max_step_um`` (host train: the training
    runs' fastest change of the model output with a margin) rounded up; a model.json without
    it gets the box's walk-back rate, 1 um/s x period."""
    if ax.max_step_um is not None:
        step_um = Fraction(ax.max_step_um)
        source = "model"
    else:
        step_um = Fraction(str(DEFAULT_AXIS_STEP_UM_PER_S)) * Fraction(period_s)
        source = "default"
    return max(1, min(math.ceil(step_um * 1000), INT32_MAX)), source


def with_service(ax: QAxis, service: ServiceSpec | None, period_s: float, start: bool) -> QAxis:
    """The axis with its estimator parameters quantised (docs/service.md, "Fixed point"),
    when model.json has a ``service`` block for it."""
    if service is None:
        return ax
    try:
        params = FixedParams.of(**service.values(), period_s=period_s, start=start)
    except CodegenError as exc:
        raise CodegenError(f"axis '{ax.name}': {exc}") from None
    return QAxis(**{**ax.__dict__, "service": params})

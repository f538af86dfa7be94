"""The box's in-service estimator in fixed point: the bit-exact twin a C implementation mirrors.

The scalar Kalman bias of ``host.service.estimators.BiasKalman`` (the default, chosen by
``python -m bench service``) in integers only; docs/service.md ("Fixed point") is the spec,
contract/service.py holds the widths. Per axis:

    state   bias_nm  int32   the correction added to the model's output (nm)
            p_q8     int64   its variance in 1/256 nm^2, 0 .. pmax_q8
    params  q_q8     int64   process noise per sample, 1/256 nm^2
            r_q8     int64   the probe's variance, 1/256 nm^2 (> 0)
            g2_q8    int64   gate_sigma^2 in Q8
            floor2   int64   gate_floor^2 in nm^2
            pmax_q8  int64   the variance's cap, 1/256 nm^2
            p0_q8    int64   its value at power-up / ZERO (0 for a start model, else pmax)
            reopen   uint8   agreeing refusals in a row that re-open the axis (0: never)

Every sample after the reference sample: ``p = min(p + q, pmax)``. The output is
``model_nm + bias_nm`` before the box's output stage (clamp, step limit). A reading ``z_nm`` of
a sample whose model output was ``model_nm`` (``measure``):

    nu = z - (model + bias)                         int64, |nu| < 2^33
    refuse if |nu| > 2^22                           (4.19 mm: no product can overflow)
    S = p + r                                       < 2^39
    accept iff nu^2 * 2^16 <= g2 * S  or  nu^2 <= floor2        (< 2^60, < 2^55)
    K = (p * 2^16 + S / 2) / S                      floor division, 0 .. 2^16
    bias = clamp(bias + rdiv(K * nu, 16), +-BIAS_MAX_NM)          |K nu| < 2^38
    p = p - rdiv(K * p, 16)                         K p < 2^54, the result >= 0

``rdiv`` is contract.fixed_point's: v / 2^f rounded half away from zero, never shifting a
negative value. A refused reading changes nothing but the re-opening streak (docs/service.md,
"Re-opening"): with reopen > 0 and |nu| <= 2^22, it joins the streak if the streak is not
empty and d = nu - anchor passes the same gate (d^2 * 2^16 <= g2 * S or d^2 <= floor2; |d| <=
2^23, d^2 * 2^16 <= 2^62), else it starts a new one (anchor = nu, agree = 1); at agree ==
reopen the reading re-opens the axis (REOPEN): bias = clamp(bias + nu, +-BIAS_MAX_NM), the
reading as it is, and p = min(r, pmax), its variance. An accepted or re-opening reading, or
one beyond 2^22, empties the streak (agree = 0).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from fractions import Fraction

from thermal_comp.codegen.errors import CodegenError
from thermal_comp.contract.fixed_point import INT32_MAX, INT32_MIN, rdiv, round_half_away
from thermal_comp.contract.model_file import ModelSpec, spec_of
from thermal_comp.contract.service import (
    BIAS_MAX_NM,
    GAIN_FRAC_BITS,
    GATE_FRAC_BITS,
    INNOVATION_MAX_NM,
    MAX_PERIOD_S,
    NM_PER_UM,
    P_FRAC_BITS,
    SERVICE_FALLBACKS,
    SERVICE_FIELDS,
    service_value_problem,
)

INT64_MAX = (1 << 63) - 1
REFUSED_IMPLAUSIBLE = "IMPLAUSIBLE"
REOPENED = "REOPEN"  # accepted: the re-opening streak reached reopen_after (docs/service.md)


def _q(value: float, scale: Fraction) -> int:
    return round_half_away(Fraction(value) * scale)


@dataclass(frozen=True)
class FixedParams:
    """One axis's estimator parameters as the box stores them (module docstring)."""

    q_q8: int
    r_q8: int
    g2_q8: int
    floor2_nm2: int
    pmax_q8: int
    p0_q8: int
    reopen_after: int = 0  # agreeing refusals in a row that re-open the axis (0: never)

    @staticmethod
    def of(q_um2_per_h: float, probe_noise_um: float, gate_sigma: float, gate_floor_um: float,
           p_max_um2: float, period_s: float, start: bool = True,
           residual_noise_um: float = 0.0, reopen_after: float = 0.0) -> FixedParams:
        """Quantise float parameters (each within contract.service.SERVICE_FIELDS, the
        period within 0 .. MAX_PERIOD_S), exactly: the float's binary value, rounded half away
        from zero. CodegenError names a parameter out of its proven range."""
        given = {"q_um2_per_h": q_um2_per_h, "probe_noise_um": probe_noise_um,
                 "gate_sigma": gate_sigma, "gate_floor_um": gate_floor_um,
                 "p_max_um2": p_max_um2, "residual_noise_um": residual_noise_um,
                 "reopen_after": reopen_after}
        for k, v in given.items():
            if problem := service_value_problem(k, v):
                raise CodegenError(f"service.{k}: {problem}")
        if not 0 < period_s <= MAX_PERIOD_S:
            raise CodegenError(f"sample_period_s {period_s!r}: the estimator's q per sample is "
                               f"proven for periods up to {MAX_PERIOD_S:g} s")
        nm2 = Fraction(NM_PER_UM * NM_PER_UM)
        q8 = Fraction(1 << P_FRAC_BITS)
        pmax = _q(p_max_um2, nm2 * q8)
        return FixedParams(
            q_q8=_q(q_um2_per_h, nm2 * q8 * Fraction(period_s) / 3600),
            # R: the probe's variance and the model's non-persistent residual's, each squared
            # as a float and quantised together (host.service.ServiceParams.r_um2 adds the same)
            r_q8=max(1, _q(probe_noise_um * probe_noise_um + residual_noise_um * residual_noise_um,
                           nm2 * q8)),
            g2_q8=_q(gate_sigma * gate_sigma, Fraction(1 << GATE_FRAC_BITS)),
            floor2_nm2=_q(gate_floor_um * gate_floor_um, nm2),
            pmax_q8=pmax, p0_q8=0 if start else pmax, reopen_after=int(reopen_after))

    @staticmethod
    def of_model(model: Mapping | ModelSpec, axis: str) -> FixedParams:
        """An axis's parameters from a model (its typed view, or the dict): its ``service``
        block, else contract.service.SERVICE_FALLBACKS; p0 = 0 for a ``start`` model, else
        p_max (as host.service.service_params)."""
        spec = spec_of(model)
        service = spec.axis(axis).service
        values = service.values() if service is not None else SERVICE_FALLBACKS
        return FixedParams.of(**{k: float(values[k]) for k in SERVICE_FIELDS},
                              period_s=spec.sample_period_s,
                              start=spec.reference.kind == "start")


@dataclass
class FixedState:
    bias_nm: int = 0
    p_q8: int = 0
    last_innovation_nm: int = 0
    refusals: int = 0  # readings refused since the last accepted one
    anchor_nm: int = 0  # the innovation of the re-opening streak's first refusal
    agree: int = 0  # refused readings in that streak (0: none)
    reopens: int = 0  # re-openings since power-up or ZERO (saturating at 65535)


@dataclass(frozen=True)
class Measured:
    """The box's answer to one reading."""

    innovation_nm: int  # saturated to int32
    accepted: bool
    reason: str  # "" when accepted, REOPENED when accepted by re-opening the axis
    bias_nm: int
    p_q8: int


def reset(params: FixedParams) -> FixedState:
    """Power-up or ZERO."""
    return FixedState(0, params.p0_q8)


def tick(state: FixedState, params: FixedParams) -> None:
    """Every sample after the reference sample, before its output."""
    state.p_q8 = min(state.p_q8 + params.q_q8, params.pmax_q8)


def _sat32(v: int) -> int:
    return max(INT32_MIN, min(INT32_MAX, v))


def _passes(v: int, s: int, params: FixedParams) -> bool:
    """The gate's test of a value v (|v| <= 2^23) against S = P + R."""
    return (v * v) << GAIN_FRAC_BITS <= params.g2_q8 * s or v * v <= params.floor2_nm2


def _reopens(state: FixedState, params: FixedParams, nu: int, s: int) -> bool:
    """A refused reading (|nu| <= 2^22) in the re-opening streak: True when it re-opens."""
    if not params.reopen_after:
        return False
    if not state.agree or not _passes(nu - state.anchor_nm, s, params):
        state.anchor_nm, state.agree = nu, 0
    state.agree += 1
    return state.agree >= params.reopen_after


def measure(state: FixedState, params: FixedParams, reading_nm: int, model_nm: int
            ) -> Measured:
    """One probe reading of a sample whose model output (before the bias) was ``model_nm``."""
    nu = int(reading_nm) - (int(model_nm) + state.bias_nm)
    state.last_innovation_nm = _sat32(nu)
    if abs(nu) > INNOVATION_MAX_NM:
        state.refusals += 1
        state.agree = 0
        return Measured(_sat32(nu), False, REFUSED_IMPLAUSIBLE, state.bias_nm, state.p_q8)
    s = state.p_q8 + params.r_q8
    if not _passes(nu, s, params):
        if not _reopens(state, params, nu, s):
            state.refusals += 1
            return Measured(nu, False, REFUSED_IMPLAUSIBLE, state.bias_nm, state.p_q8)
        state.bias_nm = max(-BIAS_MAX_NM, min(BIAS_MAX_NM, state.bias_nm + nu))
        state.p_q8 = min(params.r_q8, params.pmax_q8)
        state.reopens = min(state.reopens + 1, 0xFFFF)
        state.refusals = state.agree = 0
        return Measured(nu, True, REOPENED, state.bias_nm, state.p_q8)
    k = ((state.p_q8 << GAIN_FRAC_BITS) + s // 2) // s
    state.bias_nm = max(-BIAS_MAX_NM, min(BIAS_MAX_NM,
                                           state.bias_nm + rdiv(k * nu, GAIN_FRAC_BITS)))
    state.p_q8 -= rdiv(k * state.p_q8, GAIN_FRAC_BITS)
    state.refusals = state.agree = 0
    return Measured(nu, True, "", state.bias_nm, state.p_q8)


def run_twin(params: FixedParams, model_nm: Sequence[int], readings: Mapping[int, int]
             ) -> tuple[list[int], list[Measured]]:
    """The box over a run: per sample the bias added to its output (nm), and the answer to
    each reading (``readings``: sample -> reading in nm, taken after that sample's output)."""
    state = reset(params)
    out, answers = [], []
    for n, m in enumerate(model_nm):
        if n:
            tick(state, params)
        out.append(state.bias_nm)
        if n in readings:
            answers.append(measure(state, params, readings[n], int(m)))
    return out, answers


def to_nm(um: float) -> int:
    """A reading or model output in um to the box's int32 nanometres (half away from 0)."""
    return _sat32(round_half_away(Fraction(um) * NM_PER_UM))


# proven in docs/service.md ("Fixed point"): the products above stay below 2^63
assert (INNOVATION_MAX_NM ** 2) << GAIN_FRAC_BITS < INT64_MAX
assert 2 * BIAS_MAX_NM < INT32_MAX
assert ((2 * INNOVATION_MAX_NM) ** 2) << GAIN_FRAC_BITS <= 1 << 62  # the streak's difference

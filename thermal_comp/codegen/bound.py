"""The worst-case error of the fixed-point model against the exact real-valued model.

Computed exactly (``Fraction``) over the declared input ranges and rounded *up* to float, so
the number in the header is a proof, not an estimate. Components as in docs/fixed-point.md;
the derivations are in docs/codegen.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from fractions import Fraction

from thermal_comp.codegen.quantise import QAxis, QModel, QTerm
from thermal_comp.contract.fixed_point import ALPHA_FRAC_BITS, FINAL_ROUNDING_NM, TEMP_FRAC_BITS
from thermal_comp.contract.terms import FILTER_KINDS

__all__ = ["FINAL_ROUNDING_NM", "AxisBound", "model_bounds", "round_up"]
INPUT_HALF_LSB_C = Fraction(1, 2 << TEMP_FRAC_BITS)  # +-1/256 degC


def round_up(x: Fraction) -> float:
    """The smallest float >= x (a bound must never be rounded down)."""
    f = float(x)
    return f if Fraction(f) >= x else math.nextafter(f, math.inf)


@dataclass(frozen=True)
class TermError:
    """One term's share of the bound, nm (exact)."""

    term: QTerm
    coef_nm: Fraction
    state_nm: Fraction
    input_um: Fraction

    @property
    def total_nm(self) -> Fraction:
        return self.coef_nm + self.state_nm


@dataclass(frozen=True)
class AxisBound:
    axis: str
    coef_quantisation_um: float
    state_quantisation_um: float
    final_rounding_um: float
    bound_um: float
    input_quantisation_um: float
    bound_exact_um: Fraction
    terms: tuple[TermError, ...]

    def to_json(self) -> dict:
        return {"coef_quantisation_um": self.coef_quantisation_um,
                "state_quantisation_um": self.state_quantisation_um,
                "final_rounding_um": self.final_rounding_um,
                "bound_um": self.bound_um,
                "input_quantisation_um": self.input_quantisation_um}


def _term_error(t: QTerm, shift: int, model: QModel) -> TermError:
    coef_nm = abs(Fraction(t.coef_q, 1 << shift) - t.c) * t.xmax
    state_nm = Fraction(0)
    if t.kind in FILTER_KINDS:
        # |s - 2^16*y| < 0.5/alpha state units (docs/codegen.md), times |c| nm per unit.
        state_nm = abs(t.c) * Fraction(1, 2) * Fraction(1 << ALPHA_FRAC_BITS, t.param)
    d = INPUT_HALF_LSB_C
    coef = abs(Fraction(t.coef_um))
    if t.kind in ("temp", "lag"):
        input_um = coef * d
    elif t.kind == "rate":
        input_um = 2 * coef * d  # x - lag(x): the two perturbations can add
    elif t.kind == "square":
        ch = model.channels[t.input]
        m = Fraction(max(abs(ch.min_code - t.param), abs(ch.max_code - t.param)), 128)
        input_um = coef * (2 * m * d + d * d)
    else:
        input_um = Fraction(0)
    return TermError(t, coef_nm, state_nm, input_um)


def axis_bound(ax: QAxis, model: QModel) -> AxisBound:
    terms = tuple(_term_error(t, ax.shift, model) for t in ax.terms)
    coef_nm = abs(Fraction(ax.intercept_q, 1 << ax.shift) - ax.c0) + sum(
        (e.coef_nm for e in terms), Fraction(0))
    state_nm = sum((e.state_nm for e in terms), Fraction(0))
    total_um = (coef_nm + state_nm + FINAL_ROUNDING_NM) / 1000
    return AxisBound(
        axis=ax.name,
        coef_quantisation_um=round_up(coef_nm / 1000),
        state_quantisation_um=round_up(state_nm / 1000),
        final_rounding_um=round_up(FINAL_ROUNDING_NM / 1000),
        bound_um=round_up(total_um),
        input_quantisation_um=round_up(sum((e.input_um for e in terms), Fraction(0))),
        bound_exact_um=total_um,
        terms=terms,
    )


def model_bounds(model: QModel) -> list[AxisBound]:
    return [axis_bound(ax, model) for ax in model.axes]

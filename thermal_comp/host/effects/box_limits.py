"""What the box can run: a candidate whose fixed-point error bound would break is refused.

Part of closing the loop (docs/effects.md); host.effects.search drives the steps.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from thermal_comp.contract.fixed_point import (
    ALPHA_FRAC_BITS,
    DEFAULT_MAX_ERROR_UM,
    FINAL_ROUNDING_NM,
    STATE_LSB_C,
)
from thermal_comp.contract.terms import Term

MAX_ERROR_UM = DEFAULT_MAX_ERROR_UM  # codegen's default --max-error-um
STATE_SHARE = 0.75  # share of the codegen bound the filter states may use
FINAL_ROUNDING_UM = float(FINAL_ROUNDING_NM) / 1000.0


def state_quantisation_um(terms: Sequence[Term], coefs: Sequence[float]) -> float:
    """docs/fixed-point.md: sum over lag/rate of |c| * 0.5/alpha state units (STATE_LSB_C,
    2^-23 degC)."""
    total = 0.0
    for t, c in zip(terms, coefs, strict=True):
        if t.kind in ("lag", "rate"):
            a = round(t.params["alpha"] * (1 << ALPHA_FRAC_BITS))
            total += abs(float(c)) * float(STATE_LSB_C) * 0.5 * (1 << ALPHA_FRAC_BITS) / a
    return total


def fixed_point_refusal(terms: Sequence[Term], coefs: Sequence[float],
                        max_error_um: float = MAX_ERROR_UM) -> str | None:
    """Why codegen would refuse this axis (None if it fits the bound with margin)."""
    budget = STATE_SHARE * (max_error_um - FINAL_ROUNDING_UM)
    state = state_quantisation_um(terms, coefs)
    if state > budget:
        return (f"filter-state quantisation bound {state:.4g} um exceeds {budget:.4g} um "
                f"({STATE_SHARE:.0%} of the {max_error_um:g} um codegen bound less rounding)")
    if not all(math.isfinite(float(c)) for c in coefs):
        return "non-finite coefficient"
    return None

"""The fixed-point arithmetic contract (docs/fixed-point.md in code).

The box, the codegen twin (``codegen.fixed``) and the float reference of the host all follow
these widths and this rounding. ``firmware/include/model_eval.h`` states the same constants as
``TCM_*`` macros; tests/contract/test_contract.py parses that header and fails when the two
disagree.
"""

from __future__ import annotations

import math
from fractions import Fraction

from thermal_comp.contract.errors import InputError

TEMP_FRAC_BITS = 7  # temperature code LSB = 1/128 degC (MAX31856 LTCB >> 5)
TEMP_LSB_C = 1.0 / (1 << TEMP_FRAC_BITS)
STATE_FRAC_BITS = 16  # filter state = code * 2^16
ALPHA_FRAC_BITS = 30  # filter coefficient a = alpha * 2^30, 1 <= a <= 2^30
CODE_MIN = -(1 << 18)  # 19-bit two's complement range of the chip
CODE_MAX = (1 << 18) - 1
ACC_LIMIT = 1 << 62  # |accumulator| bound: one guard bit below int64
MAX_SHIFT = 62
INT32_MAX = (1 << 31) - 1
INT32_MIN = -(1 << 31)
UINT32_MAX = (1 << 32) - 1
# The box flags EXTRAP when a valid channel leaves its training range by more than this share
# of the range's span; host evaluate/diagnose use the same rule. Exact: window codes must not
# depend on float 0.05.
EXTRAPOLATION_MARGIN = Fraction(1, 20)
# codegen's proof of the box's error: the default bound (--max-error-um) and the final rounding
# of the output to whole nm, which no model avoids; host.effects refuses what would break them
DEFAULT_MAX_ERROR_UM = 0.01
FINAL_ROUNDING_NM = Fraction(1, 2)
# one unit of a filter state in degC: a code (TEMP_LSB_C) scaled by 2^STATE_FRAC_BITS
STATE_LSB_C = Fraction(1, 1 << (TEMP_FRAC_BITS + STATE_FRAC_BITS))


def round_half_away(x: Fraction) -> int:
    """Nearest integer, ties away from zero (the rounding used everywhere in the box)."""
    q = math.floor(abs(x) + Fraction(1, 2))
    return q if x >= 0 else -q


def rdiv(v: int, f: int) -> int:
    """v / 2^f rounded half away from zero, never shifting a negative value (as the C)."""
    half = (1 << f) >> 1
    return (v + half) >> f if v >= 0 else -((-v + half) >> f)


def div_round(v: int, n: int) -> int:
    """v / n rounded half away from zero, for any n >= 1 (rdiv is the case n = 2^f).

    The box's ZERO reference is the mean of n int32 nanometre values this way:
    ``sign(v) * floor((2|v| + n) / 2n)`` (firmware axis_output_mean_nm)."""
    if n < 1:
        raise InputError(f"div_round needs n >= 1 (got {n})")
    q = (2 * abs(v) + n) // (2 * n)
    return q if v >= 0 else -q


def quantise_alpha(tau_s: float, period_s: float) -> float:
    """alpha = 1 - exp(-period/tau), rounded to Q30 as the box stores it (never 0)."""
    if tau_s <= 0 or period_s <= 0:
        raise InputError(f"lag needs tau_s > 0 and period_s > 0 (got {tau_s}, {period_s})")
    alpha = -math.expm1(-period_s / tau_s)
    q = max(1, min(1 << ALPHA_FRAC_BITS, round(alpha * (1 << ALPHA_FRAC_BITS))))
    return q / (1 << ALPHA_FRAC_BITS)

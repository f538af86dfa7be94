"""The in-service estimator's contract (issue 42, docs/service.md): its model.json fields,
their limits, and the fixed-point widths a C implementation mirrors (``codegen.estimator``
is the bit-exact Python twin).

Stdlib only, like the rest of contract/.
"""

from __future__ import annotations

# ---- model.json: axes.<axis>.service ------------------------------------------------------
# field -> (lowest, highest, unit); the limits are what the fixed-point ranges are proven for
SERVICE_FIELDS: dict[str, tuple[float, float, str]] = {
    "q_um2_per_h": (0.0, 100.0, "um^2 per hour"),  # the bias's random walk
    "probe_noise_um": (0.01, 10.0, "um"),  # the probe's standard deviation, R = its square
    "gate_sigma": (1.0, 16.0, "standard deviations"),  # refuse |innovation| > this sqrt(P+R)
    "gate_floor_um": (0.0, 1000.0, "um"),  # ... and above this floor
    "p_max_um2": (0.01, 1000.0, "um^2"),  # the bias variance's cap (and its value at reset)
    # what the model misses that does not persist from one reading to the next (its white
    # part): a reading differs from the bias by it as by the probe's noise, R = probe^2 + it^2
    "residual_noise_um": (0.0, 10.0, "um"),
    # the gate's lock-out (docs/service.md, "Re-opening"): this many refused readings in a row
    # that agree with each other (each within the gate's own threshold of the streak's first)
    # mean the model, not the probe, is off: the axis re-opens (P = p_max, the reading taken
    # through the step limit; $M ...,A,REOPEN). 0: never (the gate alone, as before)
    "reopen_after": (0.0, 255.0, "readings"),
}
# fields whose value must be a whole number (the box keeps them in a uint8)
SERVICE_INTEGER = ("reopen_after",)
REOPEN_AFTER_DEFAULT = 3  # python -m bench service, the large miss (docs/service.md)
# fields a service block may leave out (written by host train since the field came): their value
SERVICE_OPTIONAL = {"residual_noise_um": 0.0, "reopen_after": float(REOPEN_AFTER_DEFAULT)}
SERVICE_DEFAULTS = {"probe_noise_um": 0.5, "gate_sigma": 4.0, "gate_floor_um": 3.0}
# a model trained before the service block: the estimator runs with these (docs/service.md)
SERVICE_FALLBACKS = SERVICE_DEFAULTS | SERVICE_OPTIONAL | {"q_um2_per_h": 0.5, "p_max_um2": 25.0}
MAX_PERIOD_S = 3600.0  # sample periods the estimator's q per sample is proven for


def service_value_problem(key: str, value: float) -> str:
    """Why a service block's ``key`` may not be ``value`` ("" when it may)."""
    lo, hi, unit = SERVICE_FIELDS[key]
    if not lo <= value <= hi:
        return (f"{value!r} {unit} is outside {lo:g}..{hi:g} (the range the box's fixed-point "
                "estimator is proven for, contract.service)")
    if key in SERVICE_INTEGER and value != int(value):
        return f"{value!r} {unit} is not a whole number (the box keeps it in 8 bits)"
    return ""

# ---- fixed point (docs/service.md, "Fixed point") -----------------------------------------
P_FRAC_BITS = 8  # P, q and R in 1/256 nm^2 (int64)
GAIN_FRAC_BITS = 16  # K = P / (P + R) in Q16 (0 .. 65536)
GATE_FRAC_BITS = 8  # gate_sigma^2 in Q8 (256 .. 65536)
INNOVATION_MAX_NM = 1 << 22  # |innovation| above 4.19 mm: refused before any product
# two refused innovations agree when their difference passes the gate: |d| <= 2^23, so
# d^2 << GAIN_FRAC_BITS <= 2^62 (uint64); such a reading does not join a streak
REOPEN_AFTER_MAX = 255
BIAS_MAX_NM = 500_000  # |bias| is clamped to 0.5 mm (int32 with room to spare)
NM_PER_UM = 1000

# ---- the header (codegen: TCM_AXIS<n>_SVC_*, asserted by the compiler) -----------------------
# The integer ranges the C arithmetic is proven for (docs/service.md, "Fixed point"): the
# largest values SERVICE_FIELDS and MAX_PERIOD_S allow, in the header's units.
_NM2 = NM_PER_UM * NM_PER_UM
Q_Q8_MAX = 100 * _NM2 << P_FRAC_BITS  # q 100 um^2/h over a period of at most 3600 s
R_Q8_MAX = 200 * _NM2 << P_FRAC_BITS  # probe noise 10 um and residual noise 10 um
G2_Q8_MIN, G2_Q8_MAX = 1 << GATE_FRAC_BITS, 256 << GATE_FRAC_BITS  # gate_sigma 1..16
FLOOR2_NM2_MAX = (1000 * NM_PER_UM) ** 2  # gate_floor 1000 um
PMAX_Q8_MIN, PMAX_Q8_MAX = 1, 1000 * _NM2 << P_FRAC_BITS  # p_max 0.01..1000 um^2

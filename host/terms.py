"""Model terms: the features a thermal model is linear in, computed causally as the box does.

Every term kind here exists three times and must mean the same thing in each: this float
reference (used for fitting and evaluation), the integer twin ``codegen.fixed`` and the C
runtime ``firmware/src/model_eval.c``. ``docs/fixed-point.md`` is the contract.

Parameters that the box stores in fixed point are quantised *here*, when a term is created
(``make_lag`` rounds alpha to Q30, ``make_square`` rounds the reference to 1/128 degC), so the
float model and the fixed-point model are the same function of their inputs and only the
arithmetic differs.

Kinds and their float feature value at sample n (x = sensor temperature in degC):
  temp     x[n]
  lag      y[n] = y[n-1] + alpha*(x[n] - y[n-1]), y[0] = x[0]          (degC)
  rate     x[n] - y[n], y the lag above (a smoothed derivative times tau) (degC)
  speed    aux value (rpm)
  speed2   aux value squared (rpm^2)
  square   (x[n] - ref_c)^2                                             (degC^2)
  time     n * period_s, seconds since the start of the run (box: since power-up)
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

ALPHA_FRAC_BITS = 30
TEMP_LSB_C = 1.0 / 128.0  # MAX31856 linearised temperature step
KINDS = ("temp", "lag", "rate", "speed", "speed2", "square", "time")


@dataclass(frozen=True)
class Term:
    """One model term. ``source`` is a sensor (temperature kinds) or aux column name."""

    kind: str
    source: str | None = None
    params: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"unknown term kind '{self.kind}' (known: {', '.join(KINDS)})")
        if self.kind != "time" and not self.source:
            raise ValueError(f"term kind '{self.kind}' needs a source column")

    @property
    def name(self) -> str:
        """Readable, unique name, e.g. ``lag(T07, tau=1800s)``."""
        p = self.params
        if self.kind == "temp":
            return str(self.source)
        if self.kind in ("lag", "rate"):
            return f"{self.kind}({self.source}, tau={p['tau_s']:g}s)"
        if self.kind in ("speed", "speed2"):
            return f"{self.kind}({self.source})"
        if self.kind == "square":
            return f"square({self.source}-{p['ref_c']:g}C)"
        return "time"

    def to_json(self) -> dict:
        out: dict = {"kind": self.kind}
        if self.source is not None:
            out["source"] = self.source
        out.update({k: float(v) for k, v in sorted(self.params.items())})
        return out

    @staticmethod
    def from_json(d: Mapping) -> Term:
        params = {k: float(v) for k, v in d.items() if k not in ("kind", "source", "coef")}
        return Term(d["kind"], d.get("source"), params)

    def __hash__(self) -> int:  # params is a dict; hash by content
        return hash((self.kind, self.source, tuple(sorted(self.params.items()))))

    def __eq__(self, other: object) -> bool:
        return (isinstance(other, Term) and self.kind == other.kind
                and self.source == other.source and dict(self.params) == dict(other.params))


def quantise_alpha(tau_s: float, period_s: float) -> float:
    """alpha = 1 - exp(-period/tau), rounded to Q30 as the box stores it (never 0)."""
    if tau_s <= 0 or period_s <= 0:
        raise ValueError(f"lag needs tau_s > 0 and period_s > 0 (got {tau_s}, {period_s})")
    alpha = -math.expm1(-period_s / tau_s)
    q = max(1, min(1 << ALPHA_FRAC_BITS, round(alpha * (1 << ALPHA_FRAC_BITS))))
    return q / (1 << ALPHA_FRAC_BITS)


def make_temp(sensor: str) -> Term:
    return Term("temp", sensor)


def make_lag(sensor: str, tau_s: float, period_s: float) -> Term:
    return Term("lag", sensor, {"tau_s": float(tau_s), "alpha": quantise_alpha(tau_s, period_s)})


def make_rate(sensor: str, tau_s: float, period_s: float) -> Term:
    return Term("rate", sensor, {"tau_s": float(tau_s), "alpha": quantise_alpha(tau_s, period_s)})


def make_square(sensor: str, ref_c: float) -> Term:
    return Term("square", sensor, {"ref_c": round(ref_c / TEMP_LSB_C) * TEMP_LSB_C})


def make_speed(aux: str, squared: bool = False) -> Term:
    return Term("speed2" if squared else "speed", aux)


def make_time() -> Term:
    return Term("time")


def first_order_lag(x: np.ndarray, alpha: float) -> np.ndarray:
    """y[n] = y[n-1] + alpha*(x[n]-y[n-1]) with y[0] = x[0] (cold start at the first sample)."""
    from scipy.signal import lfilter  # imported here: scipy.signal costs ~1 s at CLI start

    x = np.asarray(x, dtype=float)
    if x.size == 0:
        return x.copy()
    y, _ = lfilter([alpha], [1.0, alpha - 1.0], x, zi=[(1.0 - alpha) * x[0]])
    return y


def term_values(term: Term, columns: Mapping[str, np.ndarray], period_s: float) -> np.ndarray:
    """The float feature of one term over a run's columns (see the module docstring)."""
    if term.kind == "time":
        n = len(next(iter(columns.values())))
        return np.arange(n, dtype=float) * period_s
    if term.source not in columns:
        raise KeyError(f"term {term.name}: column '{term.source}' is not in the data")
    x = np.asarray(columns[term.source], dtype=float)
    if term.kind in ("temp", "speed"):
        return x.copy()
    if term.kind == "speed2":
        return x * x
    if term.kind == "lag":
        return first_order_lag(x, term.params["alpha"])
    if term.kind == "rate":
        return x - first_order_lag(x, term.params["alpha"])
    if term.kind == "square":
        return (x - term.params["ref_c"]) ** 2
    raise AssertionError(term.kind)


def design_matrix(terms: list[Term], columns: Mapping[str, np.ndarray],
                  period_s: float) -> np.ndarray:
    """Columns of term values, shape (n_samples, n_terms)."""
    if not terms:
        n = len(next(iter(columns.values())))
        return np.empty((n, 0))
    return np.column_stack([term_values(t, columns, period_s) for t in terms])

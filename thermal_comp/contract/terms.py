"""Model terms: the kinds a thermal model is linear in, and how a term is named and stored.

Every kind exists three times and must mean the same thing in each: the float reference of the
host (host.fitting.features), the integer twin ``codegen.fixed`` and the C runtime
``firmware/src/model_eval.c`` (``TCM_KIND_*`` in model_eval.h; tests/contract/test_contract.py
checks the codes). Parameters the box stores in fixed point are quantised when a term is created
(``make_lag`` rounds alpha to Q30, ``make_square`` rounds the reference to 1/128 degC), so the
float model and the fixed-point model are the same function of their inputs.

Kinds and their feature value at sample n (x = sensor temperature in degC):
  temp     x[n]
  lag      y[n] = y[n-1] + alpha*(x[n] - y[n-1]), y[0] = x[0]          (degC)
  rate     x[n] - y[n], y the lag above (a smoothed derivative times tau) (degC)
  speed    aux value (rpm)
  speed2   aux value squared (rpm^2)
  square   (x[n] - ref_c)^2                                             (degC^2)
  time     n * period_s, seconds since the start of the run (box: since power-up)
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

from thermal_comp.contract.errors import InputError
from thermal_comp.contract.fixed_point import TEMP_LSB_C, quantise_alpha

KIND_CODES = {"temp": 0, "lag": 1, "rate": 2, "speed": 3, "speed2": 4, "square": 5, "time": 6}
KINDS = tuple(KIND_CODES)
TEMPERATURE_KINDS = ("temp", "lag", "rate", "square")  # need a thermocouple channel
AUX_KINDS = ("speed", "speed2")  # need an auxiliary input
FILTER_KINDS = ("lag", "rate")  # carry a filter state on the box
KELVIN_KINDS = ("temp", "lag", "rate")  # features in kelvin (a square is in K^2)
TC_TYPES = {"K": 0, "J": 1}  # thermocouple types the box linearises (TCM_TC_*)


@dataclass(frozen=True)
class Term:
    """One model term. ``source`` is a sensor (temperature kinds) or aux column name."""

    kind: str
    source: str | None = None
    params: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise InputError(f"unknown term kind '{self.kind}' (known: {', '.join(KINDS)})")
        if self.kind != "time" and not self.source:
            raise InputError(f"term kind '{self.kind}' needs a source column")

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


def make_temp(sensor: str) -> Term:
    return Term("temp", sensor)


def filter_states(terms: Iterable[Term]) -> int:
    """Filter states the box spends on ``terms``: one per distinct sensor and filter
    coefficient. The lags and rates of one sensor with one time constant share a state (a rate
    is T minus the lag), on every axis (docs/fixed-point.md)."""
    return len({(t.source, t.params.get("alpha")) for t in terms if t.kind in FILTER_KINDS})


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


def term_sensors(terms) -> list[str]:
    """Thermocouple sources of ``terms`` (Term objects or model.json dicts), each once."""
    out: list[str] = []
    for t in terms:
        kind, source = (t["kind"], t.get("source")) if isinstance(t, Mapping) else (t.kind,
                                                                                    t.source)
        if kind in TEMPERATURE_KINDS and source not in out:
            out.append(str(source))
    return out

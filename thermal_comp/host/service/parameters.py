"""The estimator's parameters per axis: model.json's ``axes.<axis>.service`` block.

``host train`` derives them from its own validation: the axis's out-of-fold residual (the
final terms refitted without each fold, that fold predicted) is what the model misses on a
day it did not see, and how it wanders with time is what the estimator tracks. For lags
dt of ``WANDER_LAGS_H`` the mean squared change of the residual over dt, D(dt), is measured
within each fold (never across a fold's edge). A random walk plus white noise of variance s^2
has D(dt) = 2 s^2 + q dt, so a line through the D(dt) (least squares, both parts >= 0) gives

    q_um2_per_h = its slope,   residual_noise_um = sqrt(its intercept / 2)

The white part does not persist from one reading to the next: a reading differs from the
bias by it as by the probe's noise, so the estimator's R is probe_noise^2 + residual_noise^2
(chasing it moved the correction by noise: measured in docs/service.md). The
variance cap ``p_max_um2`` = (``P_MAX_FACTOR`` x out-of-fold RMSE)^2, clipped to
``P_MAX_CLIP_UM2``: the first reading is taken almost as it is, and the gate
(``gate_sigma`` sqrt(p_max + R)) stays below a chip's +50 um even after a week unprobed.
``probe_noise_um`` is the probe's (default 0.5 um, a shop sets its own), ``gate_sigma`` 4 and
``gate_floor_um`` 3 um (contract.service.SERVICE_DEFAULTS); ``reopen_after`` 3 (refusals in
a row that agree re-open the axis: the gate's lock-out, docs/service.md).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass

import numpy as np

from thermal_comp.contract.model_file import ModelSpec, spec_of
from thermal_comp.contract.service import (
    REOPEN_AFTER_DEFAULT,
    SERVICE_DEFAULTS,
    SERVICE_FALLBACKS,
    SERVICE_FIELDS,
)
from thermal_comp.contract.terms import Term
from thermal_comp.host.fitting import Reference, out_of_fold_predictions, stack
from thermal_comp.host.fitting.reference import segment_bounds
from thermal_comp.host.io import Run

WANDER_LAGS_H = (0.25, 0.5, 1.0, 2.0)
P_MAX_FACTOR = 4.0
P_MAX_CLIP_UM2 = (4.0, 100.0)
FALLBACK_Q_UM2_PER_H = SERVICE_FALLBACKS["q_um2_per_h"]  # a model without a service block
FALLBACK_P_MAX_UM2 = SERVICE_FALLBACKS["p_max_um2"]


@dataclass(frozen=True)
class ServiceParams:
    q_um2_per_h: float = FALLBACK_Q_UM2_PER_H
    probe_noise_um: float = SERVICE_DEFAULTS["probe_noise_um"]
    gate_sigma: float = SERVICE_DEFAULTS["gate_sigma"]
    gate_floor_um: float = SERVICE_DEFAULTS["gate_floor_um"]
    p_max_um2: float = FALLBACK_P_MAX_UM2
    # the bias's variance at power-up or ZERO: 0 for a ``start`` model (its output and the
    # probe are both zero there by definition), p_max_um2 for ``none`` (an unknown offset)
    p0_um2: float = 0.0
    residual_noise_um: float = 0.0  # the model's non-persistent residual (module docstring)
    # refused readings in a row that agree with each other before the axis re-opens (0: never)
    reopen_after: float = float(REOPEN_AFTER_DEFAULT)

    @property
    def r_um2(self) -> float:
        """R: the probe's variance and the residual's white part's (as codegen quantises it)."""
        return (self.probe_noise_um * self.probe_noise_um
                + self.residual_noise_um * self.residual_noise_um)

    def to_json(self) -> dict:
        return asdict(self)


def service_params(model: Mapping | ModelSpec, axis: str, **overrides: float) -> ServiceParams:
    """An axis's parameters: its ``service`` block, else the fallbacks; ``overrides`` win."""
    spec = spec_of(model)
    service = spec.axis(axis).service
    known = service.values() if service is not None else {}
    known |= {k: float(v) for k, v in overrides.items()}
    if "p0_um2" not in known:
        start = spec.reference.kind == "start"
        known["p0_um2"] = 0.0 if start else known.get("p_max_um2", FALLBACK_P_MAX_UM2)
    return ServiceParams(**known)


def wander(residual: np.ndarray, segments: np.ndarray, period_s: float,
           lags_h: Sequence[float] = WANDER_LAGS_H) -> dict[float, float]:
    """D(dt): the mean squared change of ``residual`` over each lag, within each segment
    (a fold); a lag no segment is long enough for is left out."""
    out = {}
    bounds = segment_bounds(segments)
    for lag_h in lags_h:
        m = int(round(lag_h * 3600.0 / period_s))
        if m < 1:
            continue
        sq, n = 0.0, 0
        for a, b in bounds:
            r = residual[a:b]
            if r.size > m:
                d = r[m:] - r[:-m]
                sq += float(np.dot(d, d))
                n += d.size
        if n:
            out[lag_h] = sq / n
    return out


def random_walk_and_noise(d: Mapping[float, float]) -> tuple[float, float]:
    """(q, white) with D(dt) ~ white + q dt by least squares, both >= 0 (two unknowns: the
    unconstrained line, else the best with one of them at 0)."""
    lags = np.array(list(d), dtype=float)
    vals = np.array(list(d.values()), dtype=float)
    fits = [(0.0, float(vals.mean())),
            (max(float(np.dot(lags, vals) / np.dot(lags, lags)), 0.0), 0.0)]
    if lags.size >= 2 and np.ptp(lags) > 0:
        q, white = np.polyfit(lags, vals, 1)
        if q >= 0 and white >= 0:
            fits.append((float(q), float(white)))
    return min(fits, key=lambda f: float(np.sum((f[1] + f[0] * lags - vals) ** 2)))


def _clip(value: float, field: str) -> float:
    lo, hi, _ = SERVICE_FIELDS[field]
    return float(min(max(value, lo), hi))


def derive_service(runs: list[Run], terms: list[Term], target: str, period_s: float,
                   n_blocks: int, reference: Reference,
                   probe_noise_um: float = SERVICE_DEFAULTS["probe_noise_um"],
                   validation_rmse_um: float | None = None) -> dict:
    """The ``service`` block of one axis from its out-of-fold residual (module docstring).

    The residual's shape comes from refitting the final terms by least squares without each
    fold; its level is the model's own ``validation_rmse_um`` when given (the ridge's
    out-of-fold error: a least-squares refit of many terms on one run's blocks wanders more
    than the model does), so D(dt) is scaled by (validation / refit RMSE)^2.
    """
    st = stack(runs, terms, target, period_s, n_blocks, reference)
    if st.n_folds < 2 or not terms:
        residual = st.y - st.y.mean()
        how = "the training residual (a single fold)"
    else:
        residual = st.y - out_of_fold_predictions(st.X, st.y, st.groups)
        how = f"the out-of-fold residual ({st.scheme})"
    oof = float(np.sqrt(np.mean(residual ** 2))) if residual.size else 0.0
    if validation_rmse_um is not None and math.isfinite(validation_rmse_um) and oof > 0:
        residual = residual * (validation_rmse_um / oof)
        how += f", scaled to the model's validation RMSE {validation_rmse_um:.3g} um"
        oof = validation_rmse_um
    d = wander(residual, st.groups, period_s)
    q, white = random_walk_and_noise(d) if d else (FALLBACK_Q_UM2_PER_H, 0.0)
    noise = _clip(math.sqrt(white / 2.0), "residual_noise_um")
    lo, hi = P_MAX_CLIP_UM2
    p_max = min(max((P_MAX_FACTOR * oof) ** 2, lo), hi)
    q = _clip(q, "q_um2_per_h") if math.isfinite(q) else FALLBACK_Q_UM2_PER_H
    sigma = SERVICE_DEFAULTS["gate_sigma"]
    r = probe_noise_um ** 2
    lags = ", ".join(f"{v:.3g} um^2 over {lag:g} h" for lag, v in d.items()) or "no lag fits"
    why = (f"q and residual noise: the line D(dt) = 2 s^2 + q dt through {how}'s mean "
           f"squared change D over dt ({lags}): s = {noise:.3g} um joins the probe's noise "
           f"in R; "
           f"p_max = ({P_MAX_FACTOR:g} x its RMSE {oof:.3g} um)^2 clipped to {lo:g}..{hi:g} "
           f"um^2, so the gate refuses above {sigma * math.sqrt(p_max + r):.3g} um at most; "
           f"{REOPEN_AFTER_DEFAULT} refusals in a row that agree re-open the axis (a model "
           "miss beyond the gate, not a chip)")
    return {"q_um2_per_h": round(q, 6), "probe_noise_um": float(probe_noise_um),
            "gate_sigma": sigma, "gate_floor_um": SERVICE_DEFAULTS["gate_floor_um"],
            "p_max_um2": round(p_max, 6), "residual_noise_um": round(noise, 6),
            "reopen_after": REOPEN_AFTER_DEFAULT, "why": why}


def add_service(model: dict, runs: list[Run], n_blocks: int, reference: Reference,
                probe_noise_um: float = SERVICE_DEFAULTS["probe_noise_um"]) -> None:
    """Write every axis's ``service`` block into a model.json dict (``host train``)."""
    period = float(model["sample_period_s"])
    for name, ax in model["axes"].items():
        terms = [Term.from_json(t) for t in ax["terms"]]
        val = ax.get("metrics", {}).get("validation_rmse_um")
        ax["service"] = derive_service(runs, terms, name, period, n_blocks, reference,
                                       probe_noise_um, None if val is None else float(val))

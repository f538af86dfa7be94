"""A model in service on one run: static, updated by the probe, and the probe alone.

Per axis, against the run's measured displacement referenced as the model's output is
(``host evaluate``'s comparison):

- ``static_rmse_um``: the model alone (no update);
- ``rmse_um``: the model plus the estimator's correction, through the box's step limit
  (``max_step_um``: the output never changes by more per sample; the correction adds to the
  model's output before that stage);
- ``probe_only_rmse_um``: re-touching off, the last reading held (no model);
- ``probe_extrapolated_rmse_um``: the line through the last two readings;
- the readings used, how many the gate refused, and the final estimate.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from thermal_comp.contract.model_file import ModelSpec, spec_of
from thermal_comp.host.fitting import rmse
from thermal_comp.host.service.estimators import (
    DEFAULT_ESTIMATOR,
    ESTIMATORS,
    ServiceTrace,
    run_estimator,
)
from thermal_comp.host.service.gate import Gate
from thermal_comp.host.service.holds import extrapolate, hold
from thermal_comp.host.service.parameters import ServiceParams, service_params
from thermal_comp.host.service.probes import ProbeReadings


def step_limited(y: np.ndarray, max_step: float | None) -> np.ndarray:
    """``y`` as the box outputs it: each sample moves at most ``max_step`` from the last."""
    if max_step is None or y.size == 0:
        return y
    d = np.diff(y)
    if np.all(np.abs(d) <= max_step):
        return y
    out = np.empty_like(y)
    out[0] = y[0]
    for i in range(1, y.size):
        out[i] = out[i - 1] + min(max(y[i] - out[i - 1], -max_step), max_step)
    return out


def updated(prediction: np.ndarray, time_s: np.ndarray, index: np.ndarray, value: np.ndarray,
            params: ServiceParams, estimator: str = DEFAULT_ESTIMATOR,
            max_step: float | None = None) -> tuple[np.ndarray, ServiceTrace]:
    """The box's output with the estimator's correction, and what the estimator did."""
    trace = run_estimator(ESTIMATORS[estimator](params), Gate(params.gate_sigma,
                                                              params.gate_floor_um),
                          params.r_um2, prediction, time_s, index, value,
                          int(params.reopen_after))
    return step_limited(prediction + trace.correction, max_step), trace


def service_axis(measured: np.ndarray, prediction: np.ndarray, time_s: np.ndarray,
                 index: np.ndarray, value: np.ndarray, params: ServiceParams,
                 estimator: str = DEFAULT_ESTIMATOR, max_step: float | None = None) -> dict:
    y, trace = updated(prediction, time_s, index, value, params, estimator, max_step)
    n = measured.size
    return {
        "rmse_um": rmse(measured - y),
        "static_rmse_um": rmse(measured - prediction),
        "probe_only_rmse_um": rmse(measured - hold(n, index, value)),
        "probe_extrapolated_rmse_um": rmse(measured - extrapolate(time_s, index, value)),
        "max_abs_um": float(np.max(np.abs(measured - y))) if n else 0.0,
        "probes": int(trace.index.size),
        "refused": trace.refused,
        "reopened": int(np.count_nonzero(trace.reopened)),
        "final_correction_um": float(trace.correction[-1]) if n else 0.0,
        "estimator": estimator,
        "service": params.to_json(),
    }


def service_metrics(model: Mapping | ModelSpec, time_s: np.ndarray,
                    measured: Mapping[str, np.ndarray], predicted: Mapping[str, np.ndarray],
                    readings: ProbeReadings,
                    estimator: str = DEFAULT_ESTIMATOR, **overrides: float) -> dict[str, dict]:
    """``service_axis`` for every axis of ``predicted`` (axes without readings: none)."""
    model = spec_of(model)
    out = {}
    for axis, pred in predicted.items():
        idx = readings.index.get(axis, np.zeros(0, dtype=int))
        val = readings.value.get(axis, np.zeros(0))
        out[axis] = service_axis(np.asarray(measured[axis], dtype=float), pred, time_s, idx,
                                 val, service_params(model, axis, **overrides), estimator,
                                 model.axis(axis).max_step_um)
    return out

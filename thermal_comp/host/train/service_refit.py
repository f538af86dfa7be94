"""`host train --service LOG.csv`: weeks of probe readings teach the model itself (issue 42).

In service the box corrects each day's miss with a bias the probe resets; what the model gets
wrong every day (a gain the training day could not pin down, an effect it showed only weakly)
is paid again every day. A service log (``host fleet export``, or any run file with the box's
channels and sparse ``probe_<axis>`` columns) holds the temperatures the box read and, at each
touch, the axis's displacement since the reference as the probe saw it.

The refit keeps the trained terms (the box's channels, filters and effects: nothing new to
read) and moves their coefficients and intercept θ as little as the training runs allow:

    min  |A_train (θ - θ0)|²  +  Σ_logs  w_log · |A_log θ - z_log|²

``A`` holds the terms' float features and a column of ones, referenced as the model is (with
``start``: the change since each run's or log's first samples; the readings are taken the same
way), ``θ0`` the trained values. The first part is exactly how much worse the training runs
fit (for least squares; for a ridge, the same curvature about its solution), so a direction
the training pinned down stays put and a direction it left loose follows the probes. A reading
is worth as many training rows as its noise allows (``reading_weight``), at most its log's
length over its readings. The refit is kept only if it predicts held-out logs better
(``refit_axis``). The fixed-point bound is checked again by codegen after the refit, as for
any model.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from thermal_comp.contract.errors import InputError
from thermal_comp.contract.model_file import ModelSpec, ServiceSpec, spec_of
from thermal_comp.host.fitting import Reference, axis_terms, design_matrix
from thermal_comp.host.io import CsvFormat, Run, load_run
from thermal_comp.host.service import logged_probes

MIN_READINGS = 3  # fewer readings per axis than this teach nothing worth a new model
KEEP_GAIN = 0.95  # the held-out readings' RMSE the refit must reach, relative to the trained


class ServiceLogError(InputError):
    """A service log the refit cannot use (no readings, other channels than the model's)."""


@dataclass(frozen=True)
class ServiceLog:
    """One log's run (the model's channels) and its readings per axis (sample, value)."""

    run: Run
    index: dict[str, np.ndarray]
    value: dict[str, np.ndarray]


def load_service_logs(paths: Sequence[str | Path], model: Mapping | ModelSpec,
                      fill_gaps: int = 0, fmt: CsvFormat | None = None) -> list[ServiceLog]:
    """Each log with the model's channels and aux inputs, and its logged readings."""
    spec = spec_of(model)
    axes = spec.axis_names
    logs = []
    for path in paths:
        run = load_run(path, [], spec.sensors, spec.aux_names, fill_gaps, fmt=fmt,
                       sensors_from="the model's channels", aux_from="an input the model reads")
        period = spec.sample_period_s
        if run.n_samples > 1 and abs(run.period_s - period) > 0.01 * period:
            raise ServiceLogError(f"{path}: sample period {run.period_s:g} s, the model's is "
                                  f"{period:g} s (its lags are per sample): resample the log")
        readings = logged_probes(path, run, axes, fmt)
        if not any(readings.count(a) for a in axes):
            raise ServiceLogError(f"{path}: no probe readings (a column probe_<axis> for "
                                  f"{', '.join(axes)} with at least one value)")
        logs.append(ServiceLog(run, readings.index, readings.value))
    return logs


def _features(model: ModelSpec, axis: str, run: Run) -> np.ndarray:
    """[1, terms] over the run, referenced as the model is: (n, 1 + n_terms)."""
    terms, _, _ = axis_terms(model, axis)
    X = design_matrix(terms, run.columns(), model.sample_period_s)
    A = np.column_stack([np.ones(run.n_samples), X])
    ref = Reference.of_model(model)
    return np.column_stack([ref.apply(A[:, j]) for j in range(A.shape[1])])


def reading_weight(service: ServiceSpec | None, train_residuals: Sequence[np.ndarray]
                   ) -> float:
    """How many training rows one reading is worth: the training residual's variance over the
    reading's (R = the probe's noise² + the residual's white part², the service block's), times
    the rows one independent piece of that residual spans ((1 + ρ) / (1 - ρ), ρ its lag-1
    autocorrelation): a smooth, small training residual outweighs a noisy reading."""
    probe, white = (0.5, 0.0) if service is None else (service.probe_noise_um,
                                                       service.residual_noise_um)
    r = probe ** 2 + white ** 2
    e = [x - x.mean() for x in train_residuals if x.size > 2]
    var = float(np.mean(np.concatenate(e) ** 2)) if e else 0.0
    if var <= 0.0:
        return 0.0
    rho = sum(float(x[1:] @ x[:-1]) for x in e) / sum(float(x @ x) for x in e)
    rho = min(max(rho, 0.0), 0.999)
    return (1.0 + rho) / (1.0 - rho) * var / max(r, 1e-12)


@dataclass(frozen=True)
class _Readings:
    """One log's readings of an axis: their features (referenced), values and row weight."""

    A: np.ndarray
    z: np.ndarray
    sqrt_w: float


def _solve(train_rows: Sequence[np.ndarray], readings: Sequence[_Readings],
           theta0: np.ndarray) -> np.ndarray:
    """θ0 + the least change that fits ``readings`` (weighted) against the training rows."""
    M = np.vstack([*train_rows, *(g.sqrt_w * g.A for g in readings)])
    r = np.concatenate([np.zeros(sum(a.shape[0] for a in train_rows)),
                        *(g.sqrt_w * (g.z - g.A @ theta0) for g in readings)])
    scale = np.maximum(np.sqrt(np.mean(M * M, axis=0)), 1e-12)  # conditioning only
    return theta0 + np.linalg.lstsq(M / scale, r, rcond=None)[0] / scale


def _rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(e * e)))


def refit_axis(model: Mapping | ModelSpec, axis: str, runs: Sequence[Run],
               logs: Sequence[ServiceLog]) -> dict | None:
    """The axis's new intercept and coefficients and the record of why; None when the logs
    hold fewer than MIN_READINGS readings of it. Kept only if, each log held out in turn,
    the refit on the others predicts its readings better than the trained model by KEEP_GAIN:
    a refit judged on days it did not see, as training is."""
    model = spec_of(model)
    ref = Reference.of_model(model)
    _, coefs, intercept = axis_terms(model, axis)
    theta0 = np.concatenate([[intercept], coefs])
    train_rows = [_features(model, axis, run) for run in runs]
    train_e = [ref.apply(run.target(axis)) - A @ theta0
               for run, A in zip(runs, train_rows, strict=True)]
    rows_per_reading = reading_weight(model.axis(axis).service, train_e)
    readings = [_Readings(_features(model, axis, log.run)[log.index[axis]], log.value[axis],
                          math.sqrt(min(rows_per_reading,
                                        log.run.n_samples / log.index[axis].size)))
                for log in logs if log.index.get(axis) is not None and log.index[axis].size]
    n_readings = sum(g.z.size for g in readings)
    if n_readings < MIN_READINGS:
        return None
    held_out_before, held_out_after = [], []
    for j, g in enumerate(readings):  # leave one log out
        theta_j = _solve(train_rows, readings[:j] + readings[j + 1:], theta0)
        held_out_before.append(g.z - g.A @ theta0)
        held_out_after.append(g.z - g.A @ theta_j)
    before = _rms(np.concatenate(held_out_before))
    after = _rms(np.concatenate(held_out_after)) if len(readings) > 1 else None
    theta = _solve(train_rows, readings, theta0)
    kept = after is not None and after <= KEEP_GAIN * before
    delta = theta - theta0 if kept else np.zeros_like(theta0)
    e_after = np.concatenate([e - A @ delta for e, A in zip(train_e, train_rows, strict=True)])
    if after is None:
        why = "one log only: none can be held out to judge a refit, the trained model kept"
    else:
        why = (f"each log held out in turn, the refit on the others predicts its readings at "
               f"{after:.3g} um against the trained model's {before:.3g} um")
        why += (": refitted on all logs" if kept else
                f", not {1 - KEEP_GAIN:.0%} better: the trained model kept")
    final = theta if kept else theta0
    return {"intercept": float(final[0]), "coefs": final[1:].tolist(), "record": {
        "logs": [str(log.run.path) for log in logs if log.index.get(axis) is not None],
        "readings": int(n_readings), "refitted": bool(kept),
        "held_out_rmse_before_um": before, "held_out_rmse_after_um": after,
        "training_rows_per_reading": [g.sqrt_w ** 2 for g in readings],
        "training_rmse_before_um": _rms(np.concatenate(train_e)),
        "training_rmse_after_um": _rms(e_after), "why": why}}


def refit_on_probes(model: dict, runs: Sequence[Run], logs: Sequence[ServiceLog]) -> dict:
    """The model with each axis refitted to the logs' readings (axes with too few readings
    unchanged, said so in their record); ``service_refit`` per axis says what changed."""
    for axis, spec in model["axes"].items():
        fit = refit_axis(model, axis, runs, logs)
        if fit is None:
            spec["service_refit"] = {"readings": 0, "why": f"fewer than {MIN_READINGS} "
                                     "readings in the service logs: the trained model kept"}
            continue
        spec["intercept"] = fit["intercept"]
        for term, c in zip(spec["terms"], fit["coefs"], strict=True):
            term["coef"] = c
        spec["service_refit"] = fit["record"]
    return model

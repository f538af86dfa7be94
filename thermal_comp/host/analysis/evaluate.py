"""`host evaluate`: how much of a run's thermal drift a model removes (on a run it never saw).

Per axis: ``rmse_um`` and ``max_abs_um`` of the residual (measured - predicted),
``raw_rms_um`` and ``raw_peak_um`` of the measured displacement itself (what the machine does
without compensation) and ``reduction_pct`` = 100 * (1 - rmse / raw_rms). Per run: the inputs
that leave their training range (host.train.ranges), where a larger error is to be expected.
Predictions use host.fitting.design_matrix with each axis's terms, so dynamic and auxiliary terms
evaluate exactly as in training (lag filters start cold at the run's first sample, like the box
at power-up).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from thermal_comp.contract.errors import InputError
from thermal_comp.contract.model_file import ModelSpec, channel_ranges, spec_of
from thermal_comp.host.fitting import Reference, axis_terms, linear_prediction, rmse
from thermal_comp.host.io import CsvFormat, Run, load_run
from thermal_comp.host.train import outside_training

DYNAMIC_KINDS = ("lag", "rate", "time")
PERIOD_TOLERANCE = 0.01


class EvaluationError(InputError):
    """The run cannot be evaluated with this model (missing column, other sample period)."""


def load_for_model(path: str | Path, model: Mapping | ModelSpec, fill_gaps: int = 0,
                   axes: list[str] | None = None, fmt: CsvFormat | None = None) -> Run:
    """Load a run with exactly the columns the model needs (temperatures within the model's
    channel ranges)."""
    spec = spec_of(model)
    axes = spec.axis_names if axes is None else axes
    return load_run(path, axes, spec.sensors, spec.aux_names, fill_gaps, fmt=fmt,
                    temperature_ranges=channel_ranges(spec), tilts=list(spec.tilts),
                    targets_from="an axis of the model", sensors_from="the model reads them",
                    aux_from="an input the model reads")


def _check_period(model: ModelSpec, run: Run) -> None:
    dynamic = any(t.kind in DYNAMIC_KINDS for a in model.axes for t in a.terms)
    period = model.sample_period_s
    if dynamic and run.n_samples > 1 and abs(run.period_s - period) > PERIOD_TOLERANCE * period:
        raise EvaluationError(f"{run.path}: sample period {run.period_s:g} s, the model's dynamic "
                              f"terms were fitted at {period:g} s; resample the run")


def model_reference(model: Mapping | ModelSpec, reference: str | None = None) -> Reference:
    """The reference to judge by: the one given, else the model's own (``none`` for old ones)."""
    own = Reference.of_model(model)
    if reference is None or reference == own.kind:
        return own
    return Reference.of_kind(reference)


def predict(model: Mapping | ModelSpec, run: Run, reference: str | None = None
            ) -> dict[str, np.ndarray]:
    """Predicted displacement (um) per axis over the run, referenced as the box outputs it
    (with ``start``: the change since the run's first samples)."""
    model = spec_of(model)
    ref = model_reference(model, reference)
    _check_period(model, run)
    columns = run.columns()
    out = {}
    for axis in model.axis_names:
        terms, coefs, intercept = axis_terms(model, axis)
        try:
            raw = linear_prediction(terms, coefs, intercept, columns, model.sample_period_s,
                                    run.n_samples)
        except KeyError as exc:
            raise EvaluationError(f"{run.path}: axis {axis}: {exc.args[0]}") from None
        out[axis] = ref.apply(raw)
    return out


def measured(model: Mapping | ModelSpec, run: Run, axis: str, reference: str | None = None
             ) -> np.ndarray:
    """The run's measured displacement of ``axis``, referenced like the prediction."""
    return model_reference(model, reference).apply(run.target(axis))


def axis_metrics(measured: np.ndarray, predicted: np.ndarray) -> dict:
    residual = measured - predicted
    raw = rmse(measured)
    err = rmse(residual)
    return {
        "rmse_um": err,
        "max_abs_um": float(np.max(np.abs(residual))),
        "raw_rms_um": raw,
        "raw_peak_um": float(np.max(np.abs(measured))),
        # no drift measured (a constant target): a reduction of nothing is undefined, not nan
        "reduction_pct": 100.0 * (1.0 - err / raw) if raw > 0 else None,
        "n_samples": int(measured.size),
    }


def evaluate_model(model: Mapping | ModelSpec, run: Run, reference: str | None = None) -> dict:
    """``{"run": path, "axes": {axis: metrics}}`` for every model axis the run measures.

    ``reference`` (``start`` or ``none``) defaults to the model's; measured and predicted
    displacement are referenced the same way."""
    model = spec_of(model)
    missing = [a for a in model.axis_names if a not in run.target_names]
    if missing:
        raise EvaluationError(f"{run.path}: no measured column for axis "
                              f"{', '.join(missing)}")
    preds = predict(model, run, reference)
    return {"run": run.path, "reference": model_reference(model, reference).kind,
            "axes": {a: axis_metrics(measured(model, run, a, reference), p)
                     for a, p in preds.items()},
            "outside_training_range": outside_training(model, run)}

"""A small model.json fitted in a blink, for HIL tests and the benchmark.

``host train`` (sensor selection, validation) takes tens of seconds on a long run; the HIL does
not care how a model was chosen, only that the box evaluates it exactly. This fits a fixed term
list by least squares (contract/terms.py features, numpy lstsq) and writes a valid model.json, so
tests can exercise every term kind the box supports on real and simulated runs.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from thermal_comp.contract import model_file
from thermal_comp.contract.terms import Term, make_lag, make_rate, make_speed, make_temp
from thermal_comp.host.fitting import design_matrix
from thermal_comp.host.fitting.step_limits import add_step_limits
from thermal_comp.host.io import load_run


def fit_example_model(data: str | Path, axes: dict[str, list[Term]],
                      aux_names: list[str] | None = None, aux_max: float = 12000.0,
                      min_c: float = -40.0, max_c: float = 200.0) -> dict:
    """A model.json dict with the given terms per axis, coefficients fitted on ``data``."""
    aux_names = list(aux_names or [])
    sensors: list[str] = []
    for terms in axes.values():
        for t in terms:
            if t.kind not in ("speed", "speed2", "time") and t.source not in sensors:
                sensors.append(str(t.source))
    run = load_run(data, targets=list(axes), sensors=sensors, aux=aux_names)
    cols = run.columns()
    period = run.period_s
    model_axes = {}
    for axis, terms in axes.items():
        x = design_matrix(terms, cols, period)
        a = np.column_stack([np.ones(run.n_samples), x])
        coef, *_ = np.linalg.lstsq(a, run.target(axis), rcond=None)
        model_axes[axis] = {
            "unit": "um",
            "intercept": float(coef[0]),
            "terms": [{**t.to_json(), "coef": float(c)} for t, c in zip(terms, coef[1:],
                                                                       strict=True)],
        }
    model = {
        "schema": "thermal-model/1",
        "tool_version": "0.1.0",
        "sample_period_s": period,
        "channels": [{"channel": i, "sensor": s, "tc_type": "K", "min_c": min_c,
                      "max_c": max_c} for i, s in enumerate(sensors)],
        "aux": [{"input": i, "name": n, "min": 0.0, "max": aux_max}
                for i, n in enumerate(aux_names)],
        "time_max_s": 604800.0,
        "axes": model_axes,
        "training": {"runs": [str(data)], "targets": list(axes), "sensors": sensors,
                     "aux": aux_names},
    }
    add_step_limits(model, [run])  # as host train does: the box's IMPLAUSIBLE and step limits
    return model


def default_terms(sensors: list[str], period_s: float, aux: str | None = None) -> list[Term]:
    """temp, lag and rate of the first sensors (+ speed if an aux column is given)."""
    terms = [make_temp(sensors[0])]
    if len(sensors) > 1:
        terms.append(make_lag(sensors[1], 30 * 60.0, period_s))
    if len(sensors) > 2:
        terms.append(make_rate(sensors[2], 10 * 60.0, period_s))
    if aux:
        terms.append(make_speed(aux))
    return terms


def fl_thermal_model(path: str | Path) -> dict:
    """The HIL's model of the real FL_THERMAL run (examples/fl_thermal_steps.csv, 15 s).

    Two axes, six channels, every temperature term kind plus the spindle speed, so a replay
    exercises temp, lag, rate and speed features and an axis-selective hold.
    """
    p = 15.0
    return fit_example_model(path, {
        "ch1_um": [make_temp("T10"), make_temp("T07"), make_lag("T04", 1800, p),
                   make_speed("spindle_rpm")],
        "ch3_um": [make_temp("T11"), make_lag("T02", 3600, p), make_rate("T03", 600, p)],
    }, aux_names=["spindle_rpm"])


def write_model(model: dict, path: str | Path) -> Path:
    """contract.model_file.write_model (schema-checked, atomic), returning the path for chaining."""
    model_file.write_model(model, path)
    return Path(path)

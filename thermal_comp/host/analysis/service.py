"""The model in service on a run (issue 42): ``host evaluate``'s per-axis updated, static and
probe-only RMSE (host.service.evaluation) for readings already made (host.commands._probes):
``rmse_um`` becomes the updated error, ``static_rmse_um`` the model alone.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from thermal_comp.contract.model_file import ModelSpec, spec_of
from thermal_comp.host.analysis.evaluate import measured, predict
from thermal_comp.host.io import CsvFormat, Run
from thermal_comp.host.service import ProbePlan, ProbeReadings, logged_probes, synthesise_probes
from thermal_comp.host.service.evaluation import service_axis, service_metrics, updated
from thermal_comp.host.service.holds import hold
from thermal_comp.host.service.parameters import service_params
from thermal_comp.host.service.probes import any_logged


def service_of(model: Mapping | ModelSpec, run: Run, readings: ProbeReadings,
               reference: str | None = None) -> dict[str, dict]:
    model = spec_of(model)
    preds = predict(model, run, reference)
    truth = {a: measured(model, run, a, reference) for a in preds}
    return service_metrics(model, run.time_s, truth, preds, readings)


def readings_for(model: Mapping | ModelSpec, run: Run, plan: ProbePlan | None,
                 reference: str | None = None, fmt: CsvFormat | None = None
                 ) -> ProbeReadings | None:
    """The readings of a run: synthesised by ``plan`` from its measured displacement of the
    model's axes it has (in the model's order), else its logged ``probe_<axis>`` columns, else
    None (``host evaluate``'s and ``host report``'s probe options)."""
    axes = [a for a in spec_of(model).axis_names if a in run.target_names]
    if plan is not None:
        truth = {a: measured(model, run, a, reference) for a in axes}
        return synthesise_probes(run, truth, plan)
    if any_logged(run.path, axes, fmt):
        return logged_probes(run.path, run, axes, fmt)
    return None


def service_day(model: Mapping | ModelSpec, run: Run, readings: ProbeReadings,
                reference: str | None = None) -> dict[str, dict]:
    """Per axis of the run with readings, what ``host report`` draws of a day in service:
    the measured displacement, the model alone (static), the box's output updated by the
    probe (host.service.evaluation.updated, through the step limit), re-touching off (the
    last reading held), the readings and whether the gate took each; ``metrics`` are
    ``host evaluate``'s for the same readings (service_axis)."""
    model = spec_of(model)
    preds = predict(model, run, reference)
    out = {}
    for axis in run.target_names:
        idx = readings.index.get(axis, np.zeros(0, dtype=int))
        if idx.size == 0:
            continue
        val = readings.value[axis]
        truth = np.asarray(measured(model, run, axis, reference), dtype=float)
        params = service_params(model, axis)
        step = model.axis(axis).max_step_um
        y, trace = updated(preds[axis], run.time_s, idx, val, params, max_step=step)
        out[axis] = {"measured": truth, "static": preds[axis], "updated": y,
                     "probe_only": hold(truth.size, idx, val), "index": trace.index,
                     "value": np.asarray(val, dtype=float), "accepted": trace.accepted,
                     "metrics": service_axis(truth, preds[axis], run.time_s, idx, val, params,
                                             max_step=step)}
    return out

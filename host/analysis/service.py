"""The model in service on a run (issue 42): ``host evaluate``'s per-axis updated, static and
probe-only RMSE (host.service.evaluation) for readings already made (host.commands._probes):
``rmse_um`` becomes the updated error, ``static_rmse_um`` the model alone.
"""

from __future__ import annotations

from host.analysis.evaluate import measured, predict
from host.io import Run
from host.service import ProbeReadings
from host.service.evaluation import service_metrics


def service_of(model: dict, run: Run, readings: ProbeReadings, reference: str | None = None
               ) -> dict[str, dict]:
    preds = predict(model, run, reference)
    truth = {a: measured(model, run, a, reference) for a in preds}
    return service_metrics(model, run.time_s, truth, preds, readings)

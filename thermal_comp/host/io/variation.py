"""Refuse training runs with nothing to learn: a fit on a constant target or constant
sensors would come out as a model of noise, so it is refused before the fit."""

from __future__ import annotations

import numpy as np

from thermal_comp.host.io.format_error import RunFormatError
from thermal_comp.host.io.run import Run


def check_variation(runs: list[Run], targets: list[str]) -> None:
    """Refuse training runs with nothing to learn: a target constant in every run, or every
    sensor constant in every run."""
    names = ", ".join(r.path for r in runs)
    for t in targets:
        values = [r.target(t) for r in runs]
        if all(np.ptp(v) == 0 for v in values):
            level = ", ".join(f"{v[0]:g}" for v in values[:3])
            raise RunFormatError(runs[0].path, f"target '{t}' is constant in every training run "
                                 f"({names}: {level} um): there is no thermal drift to model; "
                                 "is it the right column, was the probe connected?", column=t)
    if runs and all(np.ptp(r.temperatures, axis=0).max(initial=0) == 0 for r in runs):
        raise RunFormatError(runs[0].path, f"every sensor ({', '.join(runs[0].sensor_names)}) is "
                             f"constant in every training run ({names}): there is no temperature "
                             "change to learn from; were the thermocouples read?")

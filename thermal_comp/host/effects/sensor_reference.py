"""How each model sensor relates to its neighbours in training (for host diagnose).

Part of closing the loop (docs/effects.md); host.effects.search drives the steps.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from thermal_comp.host.effects.residual import noise_floor
from thermal_comp.host.fitting import fit_linear, rmse
from thermal_comp.host.io import Run


def cluster_mates(selection: Mapping | None, sensor: str) -> list[str]:
    """A sensor's redundant neighbours: the other members of its c-means group."""
    for group in (selection or {}).get("groups", []):
        if sensor in group:
            return [s for s in group if s != sensor]
    return []


MAX_MATES = 4  # mates kept per sensor, the most redundant first
MATE_POOL = 6  # cluster-mates plus the most correlated sensors, up to this many, are tried
MATE_MAX_SCATTER = 0.1  # a redundant mate predicts the sensor within 10 % of its range (RMS)


def sensor_reference(runs: Sequence[Run], sensors: Sequence[str],
                     selection: Mapping | None) -> dict:
    """How each model sensor relates to its neighbours in training (for host diagnose).

    The pool is the sensor's cluster-mates (the c-means group of the selection trace), topped
    up with the sensors most correlated with it to ``MATE_POOL``; per pool member a line
    s = a + b*m is fitted. Mates are the members whose line predicts the sensor within
    ``MATE_MAX_SCATTER`` of its range, the best ``MAX_MATES`` (if none does, the best two,
    whose scatter then makes any drift hard to prove). Also stored: the sensor's noise.
    """
    names = list(runs[0].sensor_names)
    T = np.vstack([r.temperatures for r in runs])
    seg = np.concatenate([np.full(r.n_samples, i) for i, r in enumerate(runs)])
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = np.nan_to_num(np.corrcoef(T, rowvar=False)) if len(names) > 1 else np.ones((1, 1))
    out = {}
    for s in sensors:
        if s not in names:
            continue
        i = names.index(s)
        v = T[:, i]
        cluster = [m for m in cluster_mates(selection, s) if m in names]
        order = [names[int(j)] for j in np.argsort(-np.abs(corr[i])) if int(j) != i]
        pool = (cluster + [m for m in order if m not in cluster])[:max(MATE_POOL, len(cluster))]
        pairs = {}
        for m in pool:
            x = T[:, names.index(m)]
            fit = fit_linear(x[:, None], v)
            pairs[m] = {"intercept": float(fit.intercept), "slope": float(fit.coef[0]),
                        "rmse_c": rmse(v - fit.predict(x[:, None])),
                        "from": "cluster" if m in cluster else "correlation"}
        span = max(float(np.ptp(v)), 1e-6)
        ranked = sorted(pairs, key=lambda m: pairs[m]["rmse_c"])
        good = [m for m in ranked if pairs[m]["rmse_c"] <= MATE_MAX_SCATTER * span]
        mates = good[:MAX_MATES] if good else ranked[:2]
        out[s] = {"mates": mates, "pairs": {m: pairs[m] for m in mates},
                  "noise_c": noise_floor(v, seg),
                  "range_c": [float(v.min()), float(v.max())]}
    return out

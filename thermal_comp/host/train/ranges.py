"""Is a run inside the conditions the model was trained on?

A linear thermal model is fitted over the temperatures of its training runs. Beyond them it
extrapolates, and that is where selections and effects that looked right on every training fold
break (docs/selection.md, the hotter FL cycle; docs/effects.md, square(T13) at 5000 rpm).
``host train`` stores each input's training range next to its declaration in model.json
(``channels[i].trained_min_c/_max_c``, ``aux[k].trained_min/_max``); the box flags a valid
reading beyond it (status EXTRAP, codegen turns the range into a window of codes), and
``host evaluate`` / ``host diagnose`` / the report say which inputs of a run leave it, by how
much and for how long, so a user reads a larger error as "hotter than the test", not as a
broken box. One rule everywhere: outside means beyond the range by more than
``EXTRAPOLATION_MARGIN`` (5 %) of its span.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from thermal_comp.contract.fixed_point import EXTRAPOLATION_MARGIN
from thermal_comp.contract.model_file import ModelSpec, spec_of
from thermal_comp.host.io import Run

TOLERANCE_SHARE = float(EXTRAPOLATION_MARGIN)  # a few % is noise; the FL 5000 rpm cycle: 20-41 %


def add_training_ranges(channels: Sequence[dict], aux: Sequence[dict],
                        runs: Sequence[Run]) -> None:
    """Write each wired sensor's and aux input's min/max over the training runs into its
    model.json declaration (part of the model hash: the box's EXTRAP window comes from it)."""
    for c in channels:
        values = np.concatenate([r.column(c["sensor"]) for r in runs])
        c["trained_min_c"], c["trained_max_c"] = float(np.min(values)), float(np.max(values))
    for a in aux:
        values = np.concatenate([r.column(a["name"]) for r in runs])
        a["trained_min"], a["trained_max"] = float(np.min(values)), float(np.max(values))


def training_ranges(model: Mapping | ModelSpec) -> dict[str, dict[str, float]] | None:
    """{input: {"min", "max"}} from the model's declarations, channel order then aux; None
    when the model was trained before ranges were stored."""
    spec = spec_of(model)
    out = {}
    for c in spec.channels:
        if c.trained_min_c is not None and c.trained_max_c is not None:
            out[c.sensor] = {"min": c.trained_min_c, "max": c.trained_max_c}
    for a in spec.aux:
        if a.trained_min is not None and a.trained_max is not None:
            out[a.name] = {"min": a.trained_min, "max": a.trained_max}
    return out or None


def outside_training(model: Mapping | ModelSpec, run: Run) -> list[dict] | None:
    """Inputs of ``run`` that leave their training range, in the model's input order.

    Listed when the run leaves the range by more than ``TOLERANCE_SHARE`` of its span. Per
    input: the training ``train_min``/``train_max``, the run's ``run_min``/``run_max``,
    ``beyond`` (the largest distance outside the range, in the input's unit), ``beyond_share``
    (that distance over the training span) and ``samples_outside_pct`` (samples beyond the
    tolerance). ``None`` when the model stores no training ranges.
    """
    ranges = training_ranges(model)
    if ranges is None:
        return None
    rows = []
    for name, r in ranges.items():
        if name not in run.sensor_names and name not in run.aux_names:
            continue  # the loader already refuses a run without a column the model needs
        x = run.column(name)
        lo, hi = r["min"], r["max"]
        span = hi - lo
        tol = TOLERANCE_SHARE * span
        beyond = max(float(np.max(x)) - hi, lo - float(np.min(x)), 0.0)
        if beyond <= tol:
            continue
        rows.append({"input": name, "train_min": lo, "train_max": hi,
                     "run_min": float(np.min(x)), "run_max": float(np.max(x)),
                     "beyond": beyond, "beyond_share": beyond / span if span > 0 else None,
                     "samples_outside_pct":
                         100.0 * float(np.mean((x < lo - tol) | (x > hi + tol)))})
    return rows


def input_units(model: Mapping | ModelSpec) -> dict[str, str]:
    """Thermocouples read degrees C; an aux input's unit is whatever its column holds."""
    return {s: " °C" for s in spec_of(model).sensors}


def describe(rows: list[dict] | None, units: Mapping[str, str] | None = None) -> list[str]:
    """Readable lines for ``outside_training``'s rows (empty when the run stays inside)."""
    if rows is None:
        return ["training ranges: not stored in this model (trained before they were kept)"]
    lines = []
    for r in rows:
        unit = (units or {}).get(r["input"], "")
        above = r["run_max"] - r["train_max"] >= r["train_min"] - r["run_min"]
        edge = f"maximum {r['train_max']:.4g}" if above else f"minimum {r['train_min']:.4g}"
        share = ("" if r["beyond_share"] is None
                 else f" ({100 * r['beyond_share']:.0f} % of its training span)")
        lines.append(f"outside training: {r['input']} up to {r['beyond']:.3g}{unit} "
                     f"{'above' if above else 'below'} its training {edge}{unit}{share}, "
                     f"{r['samples_outside_pct']:.0f} % of the samples outside: the model "
                     "extrapolates, expect larger errors")
    return lines

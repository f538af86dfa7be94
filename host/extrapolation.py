"""Is a run inside the conditions the model was trained on?

A linear thermal model is fitted over the temperatures of its training runs. Beyond them it
extrapolates, and that is where selections and effects that looked right on every training fold
break (docs/selection.md, the hotter FL cycle; docs/effects.md, square(T13) at 5000 rpm).
``host train`` stores each model input's training range (``training.input_ranges``);
``host evaluate`` and ``host diagnose`` say which inputs of a new run leave it, by how much and
for how long, so a user reads a larger error as "hotter than the test", not as a broken box.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from host.data import Run

# An input counts as outside when it leaves its training range by more than this share of the
# range's span: a few per cent is sensor noise and harmless; the FL 5000 rpm cycle goes 20-41 %.
TOLERANCE_SHARE = 0.05


def training_ranges(runs: Sequence[Run], inputs: Sequence[str]) -> dict[str, dict[str, float]]:
    """{input: {"min", "max"}} over all training runs (sensor or aux column names)."""
    out = {}
    for name in inputs:
        values = np.concatenate([r.column(name) for r in runs])
        out[name] = {"min": float(np.min(values)), "max": float(np.max(values))}
    return out


def outside_training(model: Mapping, run: Run) -> list[dict] | None:
    """Inputs of ``run`` that leave their training range, in the model's input order.

    Listed when the run leaves the range by more than ``TOLERANCE_SHARE`` of its span. Per
    input: the training ``train_min``/``train_max``, the run's ``run_min``/``run_max``,
    ``beyond`` (the largest distance outside the range, in the input's unit), ``beyond_share``
    (that distance over the training span) and ``samples_outside_pct`` (samples beyond the
    tolerance). ``None`` when the model predates ``training.input_ranges``.
    """
    ranges = (model.get("training") or {}).get("input_ranges")
    if ranges is None:
        return None
    rows = []
    for name, r in ranges.items():
        if name not in run.sensor_names and name not in run.aux_names:
            continue  # the loader already refuses a run without a column the model needs
        x = run.column(name)
        lo, hi = float(r["min"]), float(r["max"])
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


def input_units(model: Mapping) -> dict[str, str]:
    """Thermocouples read degrees C; an aux input's unit is whatever its column holds."""
    return {c["sensor"]: " °C" for c in model.get("channels", [])}


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

"""How fast a channel and an axis output can physically change: the box's step limits.

A thermocouple on a machine structure cannot move 100 degC in one sample, and the thermal
drift of a machine does not step. ``host train`` measures, on the training runs, the fastest
change per sample of every wired sensor and of every axis's model output, and stores a limit
of ``STEP_MARGIN`` times that (never below a floor) in model.json: ``channels[i].max_step_c``
(degC per sample) and ``axes[a].max_step_um`` (um per sample). codegen puts them into the
header; the box flags a faster reading IMPLAUSIBLE and holds the channel's last good value,
and never steps an output by more than its limit (docs/firmware.md). A model.json without
them gets codegen's conservative defaults (docs/codegen.md).

The same runs say how long a live channel reads one code: a thermocouple on a machine changes
code (1/128 degC) almost every sample, a frozen converter repeats one code forever.
``channels[i].max_still_samples`` is ``STILL_MARGIN`` times the longest run of identical codes
(the box's rounding) in any training run, at least ``STILL_FLOOR``, at most
``MAX_STILL_SAMPLES``; the box faults a channel whose code stayed the same that many samples
in a row (STUCK, docs/firmware.md). A model.json without it has no stuck check.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from thermal_comp.codegen.fixed import temp_to_code
from thermal_comp.contract.box import (
    AXIS_STEP_FLOOR_UM,
    CHANNEL_STEP_FLOOR_C,
    MAX_STILL_SAMPLES,
    STEP_MARGIN,
    STILL_FLOOR,
    STILL_MARGIN,
)
from thermal_comp.contract.terms import Term
from thermal_comp.host.fitting.features import design_matrix
from thermal_comp.host.io import Run


def fastest_step(values: np.ndarray, time_s: np.ndarray, period_s: float) -> float:
    """The largest |change| between consecutive samples, per sample period: a gap of k
    periods counts as k samples (a change over a gap is spread over it); samples closer than
    a period count as one."""
    values = np.asarray(values, dtype=float)
    if values.size < 2:
        return 0.0
    samples = np.maximum(np.diff(np.asarray(time_s, dtype=float)) / period_s, 1.0)
    return float(np.max(np.abs(np.diff(values)) / samples))


def longest_still(values: np.ndarray, time_s: np.ndarray, period_s: float) -> int:
    """The longest run of identical box codes (``codegen.fixed.temp_to_code``), in samples:
    a run of one reading is 1; a gap of k periods inside a run counts as k samples (the box
    would have read the same code all along); a missing reading (NaN) ends a run, as a chip
    fault resets the box's counter."""
    values = np.asarray(values, dtype=float)
    if values.size == 0:
        return 0
    ok = np.isfinite(values)
    codes = np.zeros(values.size, dtype=np.int64)
    codes[ok] = temp_to_code(values[ok])
    steps = np.maximum(np.rint(np.diff(np.asarray(time_s, dtype=float)) / period_s), 1)
    same = ok[1:] & ok[:-1] & (codes[1:] == codes[:-1])
    # sample j continues the run of j-1 (adding its gap's samples) or starts one (counting
    # 1 if it is a reading): the run's length at j is its start's count plus the samples
    # added since, from one cumulative sum (integers: exact); no loop over the samples
    added = np.zeros(values.size, dtype=np.int64)
    added[1:] = np.where(same, steps.astype(np.int64), 0)
    total = np.cumsum(added)
    start = np.ones(values.size, dtype=bool)
    start[1:] = ~same
    first = np.maximum.accumulate(np.where(start, np.arange(values.size), 0))
    return int(np.max(ok[first].astype(np.int64) + total - total[first]))


def still_limits(model: dict, runs: Sequence[Run]) -> dict[str, int]:
    """{sensor: max_still_samples} from the training runs."""
    period = float(model["sample_period_s"])
    out = {}
    for c in model["channels"]:
        longest = max(longest_still(r.column(c["sensor"]), r.time_s, period) for r in runs)
        out[c["sensor"]] = min(max(STILL_MARGIN * longest, STILL_FLOOR), MAX_STILL_SAMPLES)
    return out


def step_limits(model: dict, runs: Sequence[Run]) -> tuple[dict[str, float], dict[str, float]]:
    """({sensor: max_step_c}, {axis: max_step_um}) from the training runs.

    ``model`` is the dict host train is still writing (the box's limits are part of it), not
    yet a checked model, so it is read as a dict, not through ``contract.model_spec``."""
    period = float(model["sample_period_s"])
    channels = {}
    for c in model["channels"]:
        fastest = max(fastest_step(r.column(c["sensor"]), r.time_s, period) for r in runs)
        channels[c["sensor"]] = max(STEP_MARGIN * fastest, CHANNEL_STEP_FLOOR_C)
    axes = {}
    for name, ax in model["axes"].items():
        terms = [Term.from_json(t) for t in ax["terms"]]
        coefs = np.array([float(t["coef"]) for t in ax["terms"]])
        intercept = float(ax["intercept"])
        fastest = 0.0
        for r in runs:
            pred = intercept + (design_matrix(terms, r.columns(), period) @ coefs
                                if terms else np.zeros(r.n_samples))
            fastest = max(fastest, fastest_step(pred, r.time_s, period))
        axes[name] = max(STEP_MARGIN * fastest, AXIS_STEP_FLOOR_UM)
    return channels, axes


def add_step_limits(model: dict, runs: Sequence[Run]) -> None:
    """Write ``max_step_c`` and ``max_still_samples`` into every channel and ``max_step_um``
    into every axis of a model.json dict (all part of what the box computes: hashed,
    CRC-covered)."""
    channels, axes = step_limits(model, runs)
    still = still_limits(model, runs)
    for c in model["channels"]:
        c["max_step_c"] = channels[c["sensor"]]
        c["max_still_samples"] = still[c["sensor"]]
    for name, ax in model["axes"].items():
        ax["max_step_um"] = axes[name]

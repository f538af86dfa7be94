"""Validation on data the fit did not see: leave-one-run-out, or time blocks of one run.

Features are always computed on each whole run first (lag filters run causally from the run's
start, as on the box) and only then split into folds, so a fold's test rows carry the same
filter states the box would have. Folds are given as a group label per stacked sample:
- several runs: each run is a group (leave-one-run-out);
- one run: the run is cut into ``n_blocks`` contiguous time blocks (default 3), each a group;
  a fold trains on the other blocks and tests on its own. Contiguous blocks keep the strong
  autocorrelation of thermal data from leaking between train and test the way a random split
  would. For the sensor selection (``phases=True``) the cuts follow the run's heat/cool
  cycles: each moves to the nearest transition (the spindle starts or stops; without an aux
  input, the mean temperature turns) within a quarter block of the equal split, so a block is
  a whole phase of the test rather than a slice through one, as an unseen day is. The effect
  search, the fit's validation, the ridge's penalty and the nested promise keep equal blocks:
  on whole phases the effect rule missed 3 of 8 injected effects (docs/training.md).
The fits themselves (and their out-of-fold errors) are host.fitting.out_of_fold's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from thermal_comp.contract.errors import InputError
from thermal_comp.contract.terms import Term
from thermal_comp.host.fitting.features import design_matrix
from thermal_comp.host.fitting.reference import NO_REFERENCE, Reference
from thermal_comp.host.io import Run

DEFAULT_BLOCKS = 3
SNAP_SHARE = 0.25  # a block's cut moves to a heat/cool transition at most this share of a block
STEP_SHARE = 0.05  # an aux input above this share of its largest value is running
TURN_SHARE = 0.25  # a turn of the mean temperature by this share of its range (not noise)
TURN_MIN_K = 0.5  # and by at least this much: a thermocouple's noise is a tenth of it


@dataclass
class Stacked:
    """Design matrix, target and fold labels of several runs stacked row-wise."""

    X: np.ndarray
    y: np.ndarray
    groups: np.ndarray
    scheme: str  # human-readable description of the validation scheme

    @property
    def n_folds(self) -> int:
        return int(np.unique(self.groups).size)


def heat_cool_transitions(run: Run) -> np.ndarray:
    """Sample indices where a phase of the test begins: an aux input (the spindle) starts or
    stops (crosses ``STEP_SHARE`` of its largest value), or, when none does, the smoothed mean
    temperature turns between rising and falling by more than ``TURN_SHARE`` of its range and
    ``TURN_MIN_K`` (a peak's prominence: sensor noise is not a phase)."""
    n = run.n_samples
    if run.aux is not None and run.aux.size and n > 1:
        top = np.max(np.abs(run.aux), axis=0)
        moving = np.ptp(run.aux, axis=0) > 0
        if moving.any():
            running = np.abs(run.aux[:, moving]) > STEP_SHARE * top[moving]
            starts_stops = np.flatnonzero((running[1:] != running[:-1]).any(axis=1)) + 1
            if starts_stops.size:
                return starts_stops
    from scipy.signal import find_peaks  # imported here: scipy.signal costs ~1 s at CLI start

    w = max(1, n // 10)  # smoothing: a tenth of the run
    if n < 4 * w or not run.temperatures.size:
        return np.zeros(0, dtype=int)
    mean = moving_average(run.temperatures.mean(axis=1), w)
    swing = max(TURN_SHARE * float(np.ptp(mean)), TURN_MIN_K)
    turns = np.sort(np.concatenate([find_peaks(mean, prominence=swing)[0],
                                    find_peaks(-mean, prominence=swing)[0]])) + w // 2
    return turns


def moving_average(x: np.ndarray, w: int) -> np.ndarray:
    """Mean of every ``w`` consecutive samples (``np.convolve(x, np.ones(w) / w, "valid")``
    to float rounding), from one cumulative sum: linear in the run's length, where the
    convolution over a tenth of the run was quadratic (1.8 s at 346k rows). Taken about the
    first sample, so the sums stay small and lose no digits."""
    x = np.asarray(x, dtype=float)
    total = np.concatenate([[0.0], np.cumsum(x - x[0])])
    return (total[w:] - total[:-w]) / w + x[0]


def block_cuts(run: Run, n_blocks: int) -> tuple[list[int], bool]:
    """The first sample of blocks 1..n_blocks-1: the equal split, each cut moved to the
    nearest heat/cool transition within ``SNAP_SHARE`` of a block; and whether any moved."""
    n = run.n_samples
    equal = [-(-k * n // n_blocks) for k in range(1, n_blocks)]  # ceil(k n / n_blocks)
    found = heat_cool_transitions(run)
    reach = SNAP_SHARE * n / n_blocks
    cuts = []
    for c in equal:
        near = found[np.abs(found - c) <= reach]
        cuts.append(int(near[np.argmin(np.abs(near - c))]) if near.size else c)
    bounds = [0, *cuts, n]
    if any(b - a < 2 for a, b in zip(bounds, bounds[1:], strict=False)):
        return equal, False  # two cuts on one transition: keep the equal split
    return cuts, cuts != equal


def fold_groups(runs: list[Run], n_blocks: int = DEFAULT_BLOCKS, *, phases: bool = False
                ) -> tuple[np.ndarray, str]:
    """Group label per stacked sample and the scheme's description; ``phases``: one run's
    blocks are cut at its heat/cool transitions (block_cuts), else in equal parts."""
    if len(runs) >= 2:
        groups = np.concatenate([np.full(r.n_samples, i) for i, r in enumerate(runs)])
        return groups, f"leave-one-run-out ({len(runs)} runs)"
    n = runs[0].n_samples
    if not phases:
        groups = np.minimum((np.arange(n) * n_blocks) // n, n_blocks - 1)
        return groups, f"time-blocked ({n_blocks} contiguous blocks of one run)"
    cuts, moved = block_cuts(runs[0], n_blocks)
    groups = np.searchsorted(np.asarray(cuts), np.arange(runs[0].n_samples), side="right")
    how = ", cut at its heat/cool transitions" if moved else ""
    return groups, f"time-blocked ({n_blocks} contiguous blocks of one run{how})"


def penalty_groups(runs: list[Run], n_blocks: int = DEFAULT_BLOCKS) -> tuple[np.ndarray, str]:
    """The folds a ridge's penalty is chosen on, and their description: fold_groups's, except
    for exactly two days (two runs, not two pieces of one run). There each fold of
    leave-one-run-out fits on one day alone, so the folds are each run's ``n_blocks`` equal
    blocks instead (measured in docs/training.md; with three runs or more
    leave-one-run-out did better)."""
    if len(runs) != 2 or any(r.piece for r in runs):
        return fold_groups(runs, n_blocks)
    groups = np.concatenate([i * n_blocks + np.minimum((np.arange(r.n_samples) * n_blocks)
                                                       // r.n_samples, n_blocks - 1)
                             for i, r in enumerate(runs)])
    return groups, f"time-blocked ({n_blocks} contiguous blocks of each of the 2 runs)"


def common_period(runs: list[Run], tolerance: float = 0.01) -> float:
    """The sample period all runs share (dynamic terms assume one fixed period)."""
    periods = [r.period_s for r in runs]
    p0 = periods[0]
    for run, p in zip(runs, periods, strict=True):
        if abs(p - p0) > tolerance * p0:
            raise InputError(f"{run.path}: sample period {p:g} s differs from {runs[0].path} "
                             f"({p0:g} s); resample the runs to one period")
    return p0


def run_labels(runs: list[Run]) -> np.ndarray:
    """Run index per stacked sample (a reference restarts at each run's start)."""
    return np.concatenate([np.full(r.n_samples, i) for i, r in enumerate(runs)])


def stack(runs: list[Run], terms: list[Term], target: str, period_s: float,
          n_blocks: int = DEFAULT_BLOCKS, reference: Reference = NO_REFERENCE) -> Stacked:
    """Evaluate the terms on each run and stack runs with their fold labels.

    With a ``start`` reference every run is referenced at its own start, features and target
    alike, so a held-out run is scored as the unseen day it stands for. A time block of one run
    is not a new day (nothing was zeroed when it began): it keeps the run's reference.
    """
    X = np.vstack([design_matrix(terms, r.columns(), period_s) for r in runs])
    y = np.concatenate([r.target(target) for r in runs])
    groups, scheme = fold_groups(runs, n_blocks)
    per_run = run_labels(runs)
    return Stacked(reference.apply(X, per_run), reference.apply(y, per_run), groups, scheme)

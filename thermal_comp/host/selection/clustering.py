"""Hard c-means clustering (paper 000, eqs. 7-8) of sensors in the standardised (tau, r) plane.

Each iteration assigns every point to its nearest centre (eq. 8: chi_ik = 1 for the closest
centre, 0 otherwise; U in eq. 7 is that 0/1 matrix) and moves each centre to the mean of its
members, until the partition stops changing. The result depends on the starting centres, so
the algorithm runs from ``n_restarts`` seeded starts (k-means++ spreading) and keeps the
partition with the smallest within-group sum of squared distances: deterministic for a seed.

tau (seconds) and r (unitless) have unrelated scales, so both are standardised to zero mean and
unit standard deviation first; a constant coordinate is only centred.

Groups are numbered by size, smallest first (paper 000 orders the sequential selection that
way), ties broken by the group's centre (tau, then r), so labels do not depend on the seed's
arbitrary numbering.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from thermal_comp.contract.errors import InputError

DEFAULT_RESTARTS = 10
MAX_ITER = 300


@dataclass
class Clustering:
    labels: np.ndarray  # (n,) group index, 0 = smallest group
    centres: np.ndarray  # (c, 2) in the standardised plane
    inertia: float  # within-group sum of squared distances (standardised units)
    n_groups: int


def standardise(points: np.ndarray) -> np.ndarray:
    """Zero mean, unit standard deviation per column (constant columns only centred)."""
    P = np.asarray(points, dtype=float)
    sd = P.std(axis=0)
    sd[sd == 0] = 1.0
    return (P - P.mean(axis=0)) / sd


def _sq_dist(P: np.ndarray, C: np.ndarray) -> np.ndarray:
    return ((P[:, None, :] - C[None, :, :]) ** 2).sum(axis=2)


def _init_plus_plus(P: np.ndarray, c: int, rng: np.random.Generator) -> np.ndarray:
    """k-means++ starting centres: each next centre drawn with probability ~ squared distance."""
    n = P.shape[0]
    centres = [P[rng.integers(n)]]
    for _ in range(1, c):
        d2 = _sq_dist(P, np.array(centres)).min(axis=1)
        total = d2.sum()
        if total <= 0:
            centres.append(P[rng.integers(n)])
            continue
        centres.append(P[rng.choice(n, p=d2 / total)])
    return np.array(centres)


def _lloyd(P: np.ndarray, centres: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Iterate eq. 8 (nearest-centre assignment) and the mean update until nothing changes."""
    c = centres.shape[0]
    labels = np.full(P.shape[0], -1)
    for _ in range(MAX_ITER):
        d2 = _sq_dist(P, centres)
        new = np.argmin(d2, axis=1)
        # an empty group takes the point farthest from its current centre
        for g in range(c):
            if not np.any(new == g):
                own = d2[np.arange(len(new)), new]
                movable = np.array([np.sum(new == new[i]) > 1 for i in range(len(new))])
                if not movable.any():
                    break
                far = int(np.argmax(np.where(movable, own, -1.0)))
                new[far] = g
        if np.array_equal(new, labels):
            break
        labels = new
        centres = np.array([P[labels == g].mean(axis=0) if np.any(labels == g) else centres[g]
                            for g in range(c)])
    inertia = float(((P - centres[labels]) ** 2).sum())
    return labels, centres, inertia


def hard_c_means(points: np.ndarray, n_groups: int, *, n_restarts: int = DEFAULT_RESTARTS,
                 seed: int = 0, standardised: bool = True) -> Clustering:
    """Partition points (n, d) into at most ``n_groups`` hard groups (see module docstring).

    The group count is capped by the number of distinct points.
    """
    P = np.asarray(points, dtype=float)
    if P.ndim != 2 or P.shape[0] == 0:
        raise InputError("clustering needs a non-empty (n_points, n_dims) array")
    if not np.all(np.isfinite(P)):
        raise InputError("clustering input contains NaN or infinite values")
    if n_groups < 1:
        raise InputError(f"number of groups must be >= 1 (got {n_groups})")
    if standardised:
        P = standardise(P)
    distinct = np.unique(P, axis=0).shape[0]
    c = int(min(n_groups, distinct))
    rng = np.random.default_rng(seed)
    best: tuple[np.ndarray, np.ndarray, float] | None = None
    for _ in range(max(1, n_restarts)):
        result = _lloyd(P, _init_plus_plus(P, c, rng))
        if best is None or result[2] < best[2] - 1e-12:
            best = result
    assert best is not None
    labels, centres, inertia = best
    # canonical numbering: by size, then by centre coordinates
    sizes = np.bincount(labels, minlength=c)
    order = sorted(range(c), key=lambda g: (sizes[g], *centres[g].tolist()))
    rank = np.empty(c, dtype=int)
    rank[order] = np.arange(c)
    return Clustering(rank[labels], centres[order], inertia, c)

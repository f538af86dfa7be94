"""Hard c-means on constructed clusters, determinism, and agreement with sklearn KMeans."""

from __future__ import annotations

import numpy as np
from sklearn.cluster import KMeans

from thermal_comp.host.selection import hard_c_means, standardise


def _blobs(seed: int = 0):
    rng = np.random.default_rng(seed)
    centres = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0], [10.0, 10.0]])
    sizes = [3, 5, 7, 9]
    points = np.vstack([c + 0.3 * rng.normal(size=(s, 2)) for c, s in zip(centres, sizes,
                                                                           strict=True)])
    truth = np.repeat(np.arange(4), sizes)
    return points, truth


def _same_partition(a: np.ndarray, b: np.ndarray) -> bool:
    return all(len({int(x) for x in b[a == g]}) == 1 for g in np.unique(a)) and \
        len(np.unique(a)) == len(np.unique(b))


def test_recovers_well_separated_clusters():
    points, truth = _blobs()
    result = hard_c_means(points, 4, seed=0)
    assert _same_partition(result.labels, truth)
    # groups numbered by size, smallest first: sizes 3, 5, 7, 9 become groups 0..3
    assert np.bincount(result.labels).tolist() == [3, 5, 7, 9]
    assert (result.labels == truth).all()


def test_deterministic_for_a_seed():
    rng = np.random.default_rng(1)
    points = rng.normal(size=(40, 2))
    a = hard_c_means(points, 6, seed=3)
    b = hard_c_means(points, 6, seed=3)
    assert (a.labels == b.labels).all() and a.inertia == b.inertia


def test_group_count_capped_by_distinct_points():
    points = np.array([[0.0, 1.0], [0.0, 1.0], [5.0, 2.0]])
    result = hard_c_means(points, 10)
    assert result.n_groups == 2
    assert sorted(np.bincount(result.labels).tolist()) == [1, 2]


def test_axes_are_standardised_so_units_do_not_dominate():
    # delays in seconds (thousands) and r in [-1, 1]: two groups split along r only must
    # still be found after standardisation
    rng = np.random.default_rng(2)
    tau = rng.uniform(0, 3000, size=20)
    r = np.r_[np.full(10, 0.9), np.full(10, -0.9)] + 0.01 * rng.normal(size=20)
    result = hard_c_means(np.column_stack([tau, r]), 2, seed=0)
    truth = np.r_[np.zeros(10), np.ones(10)]
    assert _same_partition(result.labels, truth)


def test_inertia_matches_sklearn_kmeans():
    rng = np.random.default_rng(5)
    points = rng.normal(size=(64, 2)) * [1000.0, 0.3]
    ours = hard_c_means(points, 10, n_restarts=20, seed=0)
    km = KMeans(n_clusters=10, n_init=20, random_state=0).fit(standardise(points))
    # both are local searches: ours must be within 1 % of sklearn's best objective
    assert ours.inertia <= km.inertia_ * 1.01
    P = standardise(points)
    recomputed = sum(((P[ours.labels == g] - P[ours.labels == g].mean(axis=0)) ** 2).sum()
                     for g in range(ours.n_groups))
    assert abs(recomputed - ours.inertia) < 1e-9

"""scikit-learn's estimator checks for ThermalSensorSelector (all the checks that apply).

``parametrize_with_checks`` picks the checks for a transformer/selector (clone, get/set_params,
pickling, dtypes, NaN/inf and empty-data errors, 1-sample and 1-feature data, read-only and
F-ordered input, idempotent fit, n_features_in_, subset/order invariance of transform, ...).
None is skipped or marked as an expected failure by us. scikit-learn itself skips its array-API
check unless SCIPY_ARRAY_API=1 is set in the environment (it reports that skip); the selector
works on NumPy arrays only, so that check does not apply.

The estimator is declared to require y (``target_tags.required``): the selection is driven by
the displacement, and the checks then verify that fitting without y fails clearly.
"""

from __future__ import annotations

from sklearn.utils.estimator_checks import parametrize_with_checks

from host.selection.estimator import ThermalSensorSelector


@parametrize_with_checks([ThermalSensorSelector()])
def test_sklearn_compatible(estimator, check):
    check(estimator)

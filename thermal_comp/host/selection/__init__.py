"""Sensor selection, paper 000: correlation and time delay, hard c-means, sequential selection, EC.

The scikit-learn estimator (``ThermalSensorSelector``) is ``host.selection.estimator``, imported
on its own so that training does not pay for scikit-learn.
"""

from __future__ import annotations

from thermal_comp.host.selection.clustering import hard_c_means, standardise
from thermal_comp.host.selection.correlation import (
    cross_correlation,
    default_max_lag,
    pearson_r,
    thermal_parameters,
)
from thermal_comp.host.selection.screening import fill_free_channels, joint_l1_ranking, l1_ranking
from thermal_comp.host.selection.selector import (
    DEFAULT_BLOCKS,
    DEFAULT_GROUPS,
    DEFAULT_MAX_SENSORS,
    METHODS,
    GramCache,
    ec_reduction,
    fold_labels,
    group_refinement,
    select_sensors,
    sequential_selection,
)

__all__ = [
    "DEFAULT_BLOCKS",
    "DEFAULT_GROUPS",
    "DEFAULT_MAX_SENSORS",
    "GramCache",
    "METHODS",
    "cross_correlation",
    "default_max_lag",
    "ec_reduction",
    "fill_free_channels",
    "joint_l1_ranking",
    "l1_ranking",
    "fold_labels",
    "group_refinement",
    "hard_c_means",
    "pearson_r",
    "select_sensors",
    "sequential_selection",
    "standardise",
    "thermal_parameters",
]

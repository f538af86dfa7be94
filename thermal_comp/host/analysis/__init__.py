"""Judging a model: evaluate, diagnose, compare methods, the protocol matrix, report and plots.

``host.analysis.report`` (and its ``plots``) import matplotlib: they are imported by name,
not through this face, so that `host evaluate` stays light.
"""

from __future__ import annotations

from thermal_comp.host.analysis.compare import (
    DEFAULT_K_CORRELATED,
    EXHAUSTIVE_LIMIT,
    MethodResult,
    best_methods,
    best_subset,
    compare_methods,
)
from thermal_comp.host.analysis.diagnose import (
    DiagnoseError,
    check_sensor,
    diagnose,
    load_for_diagnosis,
    summary_lines,
)
from thermal_comp.host.analysis.evaluate import evaluate_model, load_for_model, predict
from thermal_comp.host.analysis.protocol_matrix import (
    AXES,
    PRODUCTION,
    ProtocolComparisonError,
    combine,
    compare_protocols,
    format_matrix,
    parse_runs,
    simulate_runs,
    write_outputs,
)

__all__ = [
    "AXES",
    "DEFAULT_K_CORRELATED",
    "DiagnoseError",
    "EXHAUSTIVE_LIMIT",
    "MethodResult",
    "PRODUCTION",
    "ProtocolComparisonError",
    "best_methods",
    "best_subset",
    "check_sensor",
    "combine",
    "compare_methods",
    "compare_protocols",
    "diagnose",
    "evaluate_model",
    "format_matrix",
    "load_for_diagnosis",
    "load_for_model",
    "parse_runs",
    "predict",
    "simulate_runs",
    "summary_lines",
    "write_outputs",
]

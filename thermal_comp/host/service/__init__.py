"""In service: a touch probe's occasional reading corrects the model between thermal tests.

Issue 42. One idea per module:

- ``probes``: when a probe touches the reference artifact (``ProbePlan``: every DURATION, or
  only while the spindle stands) and what it reads (the run's measured displacement since the
  reference plus noise), or a run's logged ``probe_<axis>`` column used as it is;
- ``gate``: the innovation gate that refuses an implausible reading (a chip on the artifact);
- ``estimators``: per-axis estimators of what the model misses (scalar Kalman bias, the
  default; bias + rate; a discounted bias) run over a run's predictions and readings;
- ``holds``: re-touching off without a model (the last reading held, or extrapolated);
- ``parameters``: the per-axis ``service`` block of model.json, derived by ``host train`` from
  how its out-of-fold residuals wander with time;
- ``evaluation``: static, updated and probe-only RMSE of a model on a run (``host evaluate``).

The box's fixed-point twin of the default estimator is ``codegen.estimator``; the spec is
docs/service.md.
"""

from __future__ import annotations

from thermal_comp.host.service.estimators import (
    ESTIMATORS,
    BiasGainKalman,
    BiasKalman,
    BiasRateKalman,
    DiscountedBias,
    Estimator,
    ServiceTrace,
    run_estimator,
)
from thermal_comp.host.service.gate import Gate
from thermal_comp.host.service.parameters import (
    ServiceParams,
    add_service,
    derive_service,
    service_params,
)
from thermal_comp.host.service.probes import (
    PROBE_WHEN,
    ProbePlan,
    ProbeReadings,
    logged_probes,
    probe_column,
    synthesise_probes,
)

__all__ = [
    "ESTIMATORS",
    "PROBE_WHEN",
    "BiasGainKalman",
    "BiasKalman",
    "BiasRateKalman",
    "DiscountedBias",
    "Estimator",
    "Gate",
    "ProbePlan",
    "ProbeReadings",
    "ServiceParams",
    "ServiceTrace",
    "add_service",
    "derive_service",
    "logged_probes",
    "probe_column",
    "run_estimator",
    "service_params",
    "synthesise_probes",
]

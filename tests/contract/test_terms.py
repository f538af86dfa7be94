"""Float term features: the lag filter and parameter quantisation the box relies on."""

from __future__ import annotations

import math

import numpy as np

from thermal_comp.contract.fixed_point import quantise_alpha
from thermal_comp.contract.terms import Term, make_lag, make_square
from thermal_comp.host.fitting import first_order_lag, term_values


def test_lag_matches_explicit_recursion():
    rng = np.random.default_rng(0)
    x = rng.normal(size=200).cumsum()
    alpha = 0.1
    y = np.empty_like(x)
    y[0] = x[0]
    for n in range(1, len(x)):
        y[n] = y[n - 1] + alpha * (x[n] - y[n - 1])
    np.testing.assert_allclose(first_order_lag(x, alpha), y, rtol=1e-12, atol=1e-12)


def test_lag_step_response_has_its_time_constant():
    period, tau = 1.0, 60.0
    term = make_lag("T1", tau, period)
    x = np.r_[0.0, np.ones(600)]
    y = term_values(term, {"T1": x}, period)
    # after one time constant a first-order lag reaches 1 - 1/e of a step
    assert abs(y[60] - (1 - math.exp(-1))) < 1e-3


def test_alpha_and_reference_are_stored_quantised():
    a = quantise_alpha(1800.0, 1.0)
    assert (a * 2**30) == round(a * 2**30)
    assert make_square("T1", 25.013).params["ref_c"] * 128 == round(25.013 * 128)


def test_term_json_round_trip_and_names():
    t = make_lag("T07", 1800, 1.0)
    assert t.name == "lag(T07, tau=1800s)"
    assert Term.from_json({**t.to_json(), "coef": 1.0}) == t

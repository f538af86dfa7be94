"""The float model on a run: one prediction for host evaluate and the report, and the JSON
term lists model.json writes. Expectations are computed here with numpy, independently."""

from __future__ import annotations

import numpy as np
import pytest

from thermal_comp.contract.terms import make_lag, make_temp
from thermal_comp.host.fitting import coefficient_terms, linear_prediction


def _columns(n: int = 600) -> dict[str, np.ndarray]:
    t = np.arange(n) * 10.0
    return {"time_s": t, "T1": 20 + 3 * np.sin(t / 900.0), "T2": 21 + 0.002 * t}


def test_temperature_terms_are_a_weighted_sum_plus_the_intercept():
    cols = _columns()
    got = linear_prediction([make_temp("T1"), make_temp("T2")], np.array([1.5, -0.25]), 2.0,
                            cols, 10.0, 600)
    assert np.allclose(got, 2.0 + 1.5 * cols["T1"] - 0.25 * cols["T2"], rtol=0, atol=1e-12)


def test_a_lag_is_the_first_order_filter_started_at_the_first_sample():
    """y[0] = x[0], y[k] = y[k-1] + alpha (x[k] - y[k-1]): the box's filter, here by hand."""
    cols = _columns()
    lag = make_lag("T1", 600.0, 10.0)
    alpha = lag.params["alpha"]
    x, y = cols["T1"], np.empty(600)
    y[0] = x[0]
    for k in range(1, 600):
        y[k] = y[k - 1] + alpha * (x[k] - y[k - 1])
    got = linear_prediction([lag], np.array([2.0]), 0.0, cols, 10.0, 600)
    assert np.allclose(got, 2.0 * y, rtol=0, atol=1e-9)


def test_no_terms_is_the_intercept_on_every_row():
    got = linear_prediction([], np.zeros(0), -3.5, _columns(), 10.0, 600)
    assert got.shape == (600,) and np.all(got == -3.5)


def test_a_json_term_list_gives_its_terms_and_coefficients_in_order():
    terms, coefs = coefficient_terms([{**make_temp("T2").to_json(), "coef": 0.5},
                                      {**make_lag("T1", 600.0, 10.0).to_json(), "coef": -1}])
    assert [t.name for t in terms] == ["T2", "lag(T1, tau=600s)"]
    assert coefs.dtype == float and coefs.tolist() == [0.5, -1.0]
    with pytest.raises(KeyError):
        coefficient_terms([make_temp("T1").to_json()])  # no coefficient: not a fitted term

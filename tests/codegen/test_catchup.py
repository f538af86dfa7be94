"""The filters' catch-up after a channel fault (docs/fixed-point.md, "Catch-up"; issue 41).

While a channel is missing its lag filters freeze; when it comes back after g samples they are
first run over the gap with inputs interpolated between the last valid reading and the new
one. Checked here against a float filter written out independently, and the twin's two paths
(``step`` per sample and ``evaluate_run`` over a run) against each other."""

from __future__ import annotations

import math

import numpy as np
from test_codegen_models import base, channel, term

from thermal_comp import codegen
from thermal_comp.codegen.fixed import FixedModel, temp_to_code
from thermal_comp.contract.terms import make_lag

PERIOD, TAU = 60.0, 900.0


def lag_model() -> FixedModel:
    m = base(period_s=PERIOD, channels=[channel(0, "T01")])
    m["axes"]["dz_um"] = {"unit": "um", "intercept": 0.0,
                          "terms": [term(make_lag("T01", TAU, PERIOD), 1.0)]}
    return FixedModel(codegen.generate(m).model)


def ramp(n: int = 400) -> np.ndarray:
    t = np.arange(n)
    return np.asarray(temp_to_code(20.0 + 15.0 * (1 - np.exp(-t / 80.0))), dtype=np.int64)


def float_lag(x: np.ndarray) -> float:
    a, s = 1 - math.exp(-PERIOD / TAU), float(x[0])
    for v in x[1:]:
        s += a * (v - s)
    return s


def test_after_a_gap_the_lag_is_the_filter_over_the_interpolated_readings():
    codes = ramp()
    lo, hi = 100, 250  # the channel is missing for samples [lo, hi)
    valid = np.ones((len(codes), 1), dtype=bool)
    valid[lo:hi] = False
    fm = lag_model()
    fm.reset()
    for k, c in enumerate(codes[:hi + 1]):
        fm.step([int(c)], valid_mask=int(valid[k, 0]))
    got = fm.s[0] / 65536.0  # code units
    filled = np.concatenate([codes[:lo], np.linspace(codes[lo - 1], codes[hi], hi - lo + 2)[1:]])
    want = float_lag(filled.astype(float))
    assert abs(got - want) < 0.05  # codes (1/128 degC): rounding of 150 updates
    frozen = float_lag(codes[:lo].astype(float))
    truth = float_lag(codes[:hi + 1].astype(float))
    assert abs(got - truth) < 0.2 * abs(frozen - truth)  # the point: far closer than frozen


def test_step_and_evaluate_run_agree_through_gaps():
    codes = ramp()
    valid = np.ones((len(codes), 1), dtype=bool)
    valid[50:51] = valid[120:200] = valid[300:302] = False
    fm = lag_model()
    run = fm.evaluate_run(codes.reshape(-1, 1), valid=valid)
    fm.reset()
    stepped = [fm.step([int(c)], valid_mask=int(v))[0][0] for c, v in zip(codes, valid[:, 0],
                                                                         strict=True)]
    np.testing.assert_array_equal(run[:, 0], stepped)

"""Model dicts (schema thermal-model/1) for the codegen tests, built the way `host train` does.

Parameters the box stores quantised (alpha, ref_c) come from contract.terms' make_* helpers, so
they are exactly what a trained model.json holds. Together the models cover: 1-5 terms per
axis, 1-3 axes, every term kind, filter states shared across axes, large and tiny
coefficients, negative intercepts, an all-negative channel range, a wide (-200..1300 degC)
range, a model without channels, a sub-second sample period, a `time` term that saturates
within a test run, and channels with and without a training range (one whose EXTRAP window is
clipped to the valid range).
"""

from __future__ import annotations

import copy

from thermal_comp.contract.terms import (
    make_lag,
    make_rate,
    make_speed,
    make_square,
    make_temp,
    make_time,
)


def term(t, coef: float) -> dict:
    return {**t.to_json(), "coef": coef}


def channel(i: int, sensor: str, lo: float = -40.0, hi: float = 200.0, tc: str = "K") -> dict:
    return {"channel": i, "sensor": sensor, "tc_type": tc, "min_c": lo, "max_c": hi}


def base(period_s: float = 1.0, channels=(), aux=(), time_max_s: float = 604800.0) -> dict:
    return {"schema": "thermal-model/1", "tool_version": "0.1.0", "sample_period_s": period_s,
            "channels": list(channels), "aux": list(aux), "time_max_s": time_max_s,
            "axes": {}, "training": {"runs": ["test"]}}


SPINDLE = {"input": 0, "name": "spindle_rpm", "min": 0.0, "max": 12000.0}


def one_term() -> dict:
    m = base(channels=[channel(0, "T01")])
    m["axes"]["dz_um"] = {"unit": "um", "intercept": 0.75,
                          "terms": [term(make_temp("T01"), 1.5)]}
    return m


def all_kinds() -> dict:
    """3 channels, 1 aux, 3 axes (5, 3 and 1 terms): every kind, negative intercepts."""
    p = 1.0
    trained = {"trained_min_c": 18.3, "trained_max_c": 41.7,  # as host train writes them
               "max_step_c": 0.3171, "max_still_samples": 14}
    near_edge = {"trained_min_c": -19.0, "trained_max_c": 119.5}  # window clipped to the range
    m = base(period_s=p, channels=[{**channel(0, "T01"), **trained},
                                   channel(1, "T02", tc="J"),
                                   {**channel(2, "T03", -20.0, 120.0), **near_edge}],
             aux=[SPINDLE], time_max_s=3000.0)
    m["axes"]["dx_um"] = {"unit": "um", "intercept": -3.125, "terms": [
        term(make_temp("T01"), 2.31),
        term(make_lag("T02", 60.0, p), -1.7),
        term(make_rate("T03", 20.0, p), 4.2),
        term(make_square("T01", 25.013), 0.0021),
        term(make_time(), 1.3e-4)]}
    m["axes"]["dy_um"] = {"unit": "um", "intercept": 0.4, "terms": [
        term(make_speed("spindle_rpm"), 2.5e-4),
        term(make_speed("spindle_rpm", squared=True), -3.1e-8),
        term(make_lag("T01", 300.0, p), 0.9)]}
    m["axes"]["dz_um"] = {"unit": "um", "intercept": -12.5, "terms": [
        term(make_rate("T02", 120.0, p), -6.0)], "max_step_um": 2.0004}
    return m


def large_coefficients() -> dict:
    """Near the int32 nanometre output limit: +-200 degC x 900 um/degC ~ 0.4 m."""
    m = base(channels=[channel(0, "T01", -200.0, 200.0), channel(1, "T02")])
    m["axes"]["dx_um"] = {"unit": "um", "intercept": -1500.0, "terms": [
        term(make_temp("T01"), 900.0), term(make_temp("T02"), -750.0),
        term(make_lag("T02", 3600.0, 1.0), 20.0)]}
    m["axes"]["dz_um"] = {"unit": "um", "intercept": 250000.0, "terms": [
        term(make_square("T01", 0.0), 8.0)]}
    return m


def tiny_coefficients() -> dict:
    m = base(channels=[channel(0, "T01"), channel(1, "T02")])
    m["axes"]["dz_um"] = {"unit": "um", "intercept": -1e-6, "terms": [
        term(make_temp("T01"), 3e-9), term(make_rate("T02", 30.0, 1.0), -7e-10),
        term(make_square("T02", -5.5), 1e-12), term(make_temp("T02"), 0.0)]}
    return m


def negative_range() -> dict:
    """Every code negative (a cryogenic test rig): the rounding of negatives everywhere."""
    m = base(channels=[channel(0, "C1", -150.0, -10.0), channel(1, "C2", -190.0, -60.5)])
    m["axes"]["dz_um"] = {"unit": "um", "intercept": -7.0, "terms": [
        term(make_temp("C1"), 0.37), term(make_lag("C2", 45.0, 1.0), -2.2),
        term(make_rate("C1", 10.0, 1.0), 1.1)]}
    m["axes"]["dy_um"] = {"unit": "um", "intercept": 2.0, "terms": [
        term(make_square("C2", -100.0), -0.0013)]}
    return m


def wide_range() -> dict:
    """A furnace-range channel (-200..1300 degC) with fast filters."""
    m = base(channels=[channel(0, "F1", -200.0, 1300.0)])
    m["axes"]["dx_um"] = {"unit": "um", "intercept": 1.0, "terms": [
        term(make_temp("F1"), 0.11), term(make_lag("F1", 5.0, 1.0), 0.07),
        term(make_rate("F1", 8.0, 1.0), -0.05)]}
    return m


def aux_and_time_only() -> dict:
    """No thermocouple at all; a time term that saturates after 40 samples at 0.5 s."""
    m = base(period_s=0.5, aux=[SPINDLE, {"input": 1, "name": "feed", "min": -500.0,
                                           "max": 500.0}], time_max_s=20.0)
    m["axes"]["dz_um"] = {"unit": "um", "intercept": -0.3, "terms": [
        term(make_speed("spindle_rpm"), 1e-4), term(make_speed("feed"), -2e-3),
        term(make_speed("feed", squared=True), 4e-7), term(make_time(), 0.05)]}
    return m


def shared_filters() -> dict:
    """The box's lag pool: lags and rates of one sensor and time constant on every axis share
    one filter state (3 distinct filters for 7 filter terms), and a fault on T02 freezes the
    state that T02's terms share."""
    p = 2.0
    m = base(period_s=p, channels=[channel(0, "T01"), channel(1, "T02", -20.0, 120.0)])
    pool = [make_lag("T01", 600.0, p), make_lag("T02", 600.0, p), make_lag("T01", 3600.0, p)]
    coefs = (-0.8, 0.3, 2.1)
    m["axes"]["dx_um"] = {"unit": "um", "intercept": 0.5, "terms": [
        term(make_temp("T01"), 1.2), *(term(t, c) for t, c in zip(pool, coefs, strict=True))]}
    m["axes"]["dy_um"] = {"unit": "um", "intercept": -1.5, "terms": [
        term(make_rate("T01", 600.0, p), 3.3), term(pool[2], -0.45), term(pool[1], 0.7)]}
    m["axes"]["dz_um"] = {"unit": "um", "intercept": 2.0, "terms": [
        term(pool[1], -1.1), term(make_temp("T02"), 0.25)]}
    return m


MODELS = {
    "one_term": one_term,
    "shared_filters": shared_filters,
    "all_kinds": all_kinds,
    "large_coefficients": large_coefficients,
    "tiny_coefficients": tiny_coefficients,
    "negative_range": negative_range,
    "wide_range": wide_range,
    "aux_and_time_only": aux_and_time_only,
}


def model(name: str) -> dict:
    return copy.deepcopy(MODELS[name]())

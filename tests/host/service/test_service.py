"""In service (issue 42): the gate, the estimator, the fixed-point twin, probe readings."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest

from thermal_comp.codegen.estimator import FixedParams, measure, reset, run_twin, to_nm
from thermal_comp.contract.model_file import SCHEMA, ModelFormatError, check_model
from thermal_comp.host.io import RunFormatError, load_run
from thermal_comp.host.service import (
    BiasGainKalman,
    BiasKalman,
    Gate,
    ProbePlan,
    ServiceParams,
    logged_probes,
    run_estimator,
    synthesise_probes,
)
from thermal_comp.host.service.evaluation import updated
from thermal_comp.host.service.probes import probe_samples

ROOT = Path(__file__).resolve().parents[3]
SIM_RUN = ROOT / "examples" / "sim_random.csv"
FL_RUN = ROOT / "examples" / "fl_thermal_steps.csv"
PARAMS = ServiceParams(q_um2_per_h=0.5, probe_noise_um=0.5, gate_sigma=4.0, gate_floor_um=3.0,
                       p_max_um2=25.0, p0_um2=0.0)
# the twin's bias against the float estimator's on a real run (docs/service.md)
TWIN_BOUND_UM = 0.005


def hourly(n: int, period_s: float = 60.0) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(n) * period_s
    return t, np.arange(60, n, 60)


def test_the_gate_refuses_a_chip_and_nothing_changes():
    t, idx = hourly(600)
    pred = np.zeros(t.size)
    truth = np.full(t.size, 2.0)  # the model misses 2 um
    z = truth[idx].copy()
    clean = run_estimator(BiasKalman(0.5, 25.0, 0.0), Gate(4.0, 3.0), 0.25, pred, t, idx, z)
    z[4] += 50.0  # a chip on the artifact at the 5th touch
    chip = run_estimator(BiasKalman(0.5, 25.0, 0.0), Gate(4.0, 3.0), 0.25, pred, t, idx, z)
    assert list(chip.accepted) == [True] * 4 + [False] + [True] * (idx.size - 5)
    # refused and changed nothing: the output up to then is the clean run's, and it stays
    # where it was until the next touch
    assert np.array_equal(chip.correction[:idx[4] + 1], clean.correction[:idx[4] + 1])
    assert np.all(chip.correction[idx[4] + 1:idx[5] + 1] == chip.correction[idx[4]])
    # even at the cap (a week unprobed) the gate stays below a chip
    assert Gate(4.0, 3.0).threshold(25.0 + 0.25) < 50.0


def test_the_fixed_point_gate_refuses_a_chip():
    p = FixedParams.of(0.5, 0.5, 4.0, 3.0, 25.0, 60.0, start=False)  # P at its cap
    state = reset(p)
    before = (state.bias_nm, state.p_q8)
    answer = measure(state, p, to_nm(50.0), 0)
    assert not answer.accepted and answer.reason == "IMPLAUSIBLE"
    assert answer.innovation_nm == 50_000
    assert (state.bias_nm, state.p_q8) == before
    assert measure(state, p, to_nm(5.0), 0).accepted


def test_the_estimator_converges_to_a_constant_offset():
    t, idx = hourly(60 * 24)
    pred = np.sin(t / 7200.0)  # whatever the model says, it misses by +3 um
    z = pred[idx] + 3.0 + np.random.default_rng(1).normal(0, 0.5, idx.size)
    y, trace = updated(pred, t, idx, z, PARAMS)
    assert trace.refused == 0
    assert abs(trace.correction[-1] - 3.0) < 0.5
    tail = slice(idx[8], None)
    assert np.sqrt(np.mean((y[tail] - (pred[tail] + 3.0)) ** 2)) < 0.5


def test_the_twin_stays_within_its_bound_on_a_real_run():
    run = load_run(FL_RUN, ["ch3_um"], "T*", ["spindle_rpm"])
    y = run.target("ch3_um")
    # a model that misses slowly: a least-squares fit of the run, drifting by 0.3 um/h
    X = np.column_stack([np.ones(run.n_samples), run.temperatures])
    pred = X @ np.linalg.lstsq(X, y, rcond=None)[0] + 0.3 * run.time_s / 3600.0
    plan = ProbePlan(3600.0, 0.5, 3)
    rd = synthesise_probes(run, {"ch3_um": y}, plan)
    idx, z = rd.index["ch3_um"], rd.value["ch3_um"]
    params = ServiceParams(1.0, 0.5, 4.0, 3.0, 100.0, p0_um2=100.0)
    trace = run_estimator(BiasKalman(1.0, 100.0, 100.0), Gate(4.0, 3.0), 0.25, pred,
                          run.time_s, idx, z)
    fixed = FixedParams.of(params.q_um2_per_h, params.probe_noise_um, params.gate_sigma,
                           params.gate_floor_um, params.p_max_um2, run.period_s, start=False)
    model_nm = [to_nm(v) for v in pred]
    bias_nm, answers = run_twin(fixed, model_nm, {int(k): to_nm(v) for k, v in zip(idx, z,
                                                                                   strict=True)})
    assert [a.accepted for a in answers] == list(trace.accepted)
    assert trace.accepted.sum() >= 20
    diff = np.abs(np.asarray(bias_nm) / 1000.0 - trace.correction)
    assert diff.max() <= TWIN_BOUND_UM


def test_stopped_probes_only_while_the_spindle_stands():
    run = load_run(SIM_RUN, ["dz_um"], "T*", ["spindle_rpm"])
    rpm = run.column("spindle_rpm")
    idx = probe_samples(run, ProbePlan(1800.0, 0.5, 0, "stopped"))
    assert idx.size >= 3
    assert np.all(np.abs(rpm[idx]) <= 1.0)
    assert np.all(np.diff(run.time_s[idx]) >= 1800.0)
    every = probe_samples(run, ProbePlan(1800.0, 0.5, 0, "interval"))
    assert np.any(np.abs(rpm[every]) > 1.0)  # the clock does not wait for the spindle


def _with_probe_column(tmp_path: Path, cells: dict[int, str]) -> Path:
    lines = SIM_RUN.read_text().splitlines()
    out = [lines[0] + ",probe_dz_um"]
    for i, line in enumerate(lines[1:]):
        out.append(line + "," + cells.get(i, ""))
    path = tmp_path / "logged.csv"
    path.write_text("\n".join(out) + "\n")
    return path


def test_a_sparse_logged_probe_column_is_used_as_it_is(tmp_path):
    path = _with_probe_column(tmp_path, {100: "1.25", 400: "-0.5", 700: "3"})
    run = load_run(path, ["dz_um"], "T*", ["spindle_rpm"])
    rd = logged_probes(path, run, ["dz_um", "dy_um"])
    assert list(rd.index["dz_um"]) == [100, 400, 700]
    assert list(rd.value["dz_um"]) == [1.25, -0.5, 3.0]
    assert "dy_um" not in rd.index


def test_a_malformed_probe_cell_names_file_line_and_column(tmp_path):
    path = _with_probe_column(tmp_path, {100: "1.25", 400: "chip?"})
    with pytest.raises(RunFormatError) as exc:  # the run's own loader reads every cell
        logged_probes(path, load_run(path, ["dz_um"], "T*", ["spindle_rpm"]), ["dz_um"])
    assert exc.value.line == 402 and exc.value.column == "probe_dz_um"
    assert str(path) in str(exc.value)


def test_a_service_field_out_of_range_is_named():
    model = {"schema": SCHEMA, "sample_period_s": 60.0,
             "channels": [{"channel": 0, "sensor": "T01"}],
             "axes": {"dz_um": {"intercept": 0.0,
                                "terms": [{"kind": "temp", "source": "T01", "coef": 1.5}]}}}
    axis = next(iter(model["axes"]))
    good = copy.deepcopy(model)
    good["axes"][axis]["service"] = {"q_um2_per_h": 0.5, "probe_noise_um": 0.5,
                                     "gate_sigma": 4.0, "gate_floor_um": 3.0,
                                     "p_max_um2": 25.0, "why": "test"}
    check_model(good)
    bad = copy.deepcopy(good)
    bad["axes"][axis]["service"]["gate_sigma"] = 40.0
    with pytest.raises(ModelFormatError, match=r"service\.gate_sigma: 40.0 .* 1\.\.16"):
        check_model(bad)


def test_the_wander_splits_into_a_random_walk_and_white_noise():
    """A residual made of a random walk (q um^2/h) and white noise (s um), generated here: the
    line through D(dt) gives both back; the white part joins R, the walk stays q."""
    from thermal_comp.host.service.parameters import random_walk_and_noise, wander

    rng = np.random.default_rng(7)
    period_s, q, s = 15.0, 2.0, 0.4
    n = 40 * 4 * 240  # 40 folds of 4 h
    walk = np.cumsum(rng.normal(0.0, np.sqrt(q * period_s / 3600.0), n))
    residual = walk + rng.normal(0.0, s, n)
    folds = np.repeat(np.arange(40), n // 40)
    q_fit, white = random_walk_and_noise(wander(residual, folds, period_s))
    assert q_fit == pytest.approx(q, rel=0.15)
    assert np.sqrt(white / 2) == pytest.approx(s, rel=0.15)
    # a pure random walk has no white part to speak of, pure noise no walk
    _, white0 = random_walk_and_noise(wander(walk, folds, period_s))
    q0, _ = random_walk_and_noise(wander(rng.normal(0.0, s, n), folds, period_s))
    assert white0 < 0.05 and q0 < 0.05


def test_the_residual_noise_joins_the_probe_noise_in_r():
    """R = probe^2 + residual^2 on the host and, quantised, on the box; 0 leaves R as before
    (a model trained before the field)."""
    p = ServiceParams(probe_noise_um=0.5, residual_noise_um=0.3)
    assert p.r_um2 == pytest.approx(0.34)
    old = FixedParams.of(0.5, 0.5, 4.0, 3.0, 25.0, 60.0)
    new = FixedParams.of(0.5, 0.5, 4.0, 3.0, 25.0, 60.0, residual_noise_um=0.3)
    assert old.r_q8 == 250_000 * 256  # 0.25 um^2 in 1/256 nm^2
    assert new.r_q8 == 340_000 * 256
    assert FixedParams.of(0.5, 0.5, 4.0, 3.0, 25.0, 60.0, residual_noise_um=0.0) == old


# ---- the gate's lock-out (docs/service.md, "Re-opening") -----------------------------------

def _miss_run(offset_um: float, chips: dict[int, float] | None = None):
    """A day probed hourly whose model misses by ``offset_um`` from the start (a crash
    re-clamp), plus chips (reading number -> um) on some readings."""
    t, idx = hourly(60 * 24)
    pred = np.sin(t / 7200.0)
    z = pred[idx] + offset_um + np.random.default_rng(3).normal(0, 0.5, idx.size)
    for j, um in (chips or {}).items():
        z[j] += um
    return t, idx, pred, z


@pytest.mark.parametrize("after", [0, 3])
def test_a_model_miss_beyond_the_gate_reopens_after_k_agreeing_refusals(after):
    t, idx, pred, z = _miss_run(60.0)
    trace = run_estimator(BiasKalman(0.5, 25.0, 0.0), Gate(4.0, 3.0), 0.25, pred, t, idx, z,
                          reopen_after=after)
    if not after:  # the lock-out: every honest reading refused, the output never moves
        assert not trace.accepted.any() and np.all(trace.correction == 0.0)
        return
    assert list(trace.accepted[:4]) == [False, False, True, True]
    assert list(np.flatnonzero(trace.reopened)) == [2] and trace.accepted[2:].all()
    tail = slice(idx[3], None)  # from the reading after the re-opening on: the noise
    assert np.sqrt(np.mean((pred[tail] + trace.correction[tail] - pred[tail] - 60.0) ** 2)) < 0.5


def test_chips_that_do_not_agree_never_reopen():
    """One chip, and chips two readings apart or of other sizes, are refused and change
    nothing; three in a row that agree are the model's miss as far as any rule can tell."""
    t, idx, pred, z = _miss_run(0.0, {4: 50.0, 6: 50.0, 7: 90.0, 8: 50.0, 10: 50.0})
    trace = run_estimator(BiasKalman(0.5, 25.0, 0.0), Gate(4.0, 3.0), 0.25, pred, t, idx, z,
                          reopen_after=3)
    assert not trace.reopened.any()
    refused = [4, 6, 7, 8, 10]
    assert list(np.flatnonzero(~trace.accepted)) == refused
    # as if those readings had never been taken
    keep = np.setdiff1d(np.arange(idx.size), refused)
    without = run_estimator(BiasKalman(0.5, 25.0, 0.0), Gate(4.0, 3.0), 0.25, pred, t,
                            idx[keep], z[keep], reopen_after=3)
    assert np.allclose(trace.correction, without.correction, rtol=0, atol=1e-12)


def test_the_twin_reopens_where_the_float_does():
    t, idx, pred, z = _miss_run(60.0, {10: 50.0})
    trace = run_estimator(BiasKalman(0.5, 25.0, 0.0), Gate(4.0, 3.0), 0.25, pred, t, idx, z,
                          reopen_after=3)
    fixed = FixedParams.of(0.5, 0.5, 4.0, 3.0, 25.0, 60.0, reopen_after=3)
    bias_nm, answers = run_twin(fixed, [to_nm(v) for v in pred],
                                {int(k): to_nm(v) for k, v in zip(idx, z, strict=True)})
    assert [a.accepted for a in answers] == list(trace.accepted)
    assert [a.reason == "REOPEN" for a in answers] == list(trace.reopened)
    assert np.abs(np.asarray(bias_nm) / 1000.0 - trace.correction).max() <= TWIN_BOUND_UM


@pytest.mark.parametrize("value, needle", [(2.5, "whole number"), (256, "outside 0..255"),
                                           (-1, "outside 0..255")])
def test_reopen_after_is_a_whole_number_of_readings(value, needle):
    m = {"schema": SCHEMA, "sample_period_s": 60.0, "channels": [], "axes": {"dz_um": {
        "unit": "um", "intercept": 0.0, "terms": [], "service": {
            "q_um2_per_h": 0.5, "probe_noise_um": 0.5, "gate_sigma": 4.0, "gate_floor_um": 3.0,
            "p_max_um2": 25.0, "reopen_after": value}}}}
    with pytest.raises(ModelFormatError, match=needle):
        check_model(m)


def test_gain_estimator_follows_a_model_whose_gain_is_off_where_a_bias_cannot():
    """A model 20 % short of a growing drift: readings every hour, exact. Between readings the
    bias stays while the drift grows; the gain correction grows with the model's output."""
    t = np.arange(0.0, 8 * 3600.0, 60.0)
    true = 30.0 * (1.0 - np.exp(-t / 7200.0))  # um, the axis's drift from the reference
    pred = 0.8 * true
    idx = np.arange(60, t.size, 60)
    gate = Gate(4.0, 3.0)
    bias = run_estimator(BiasKalman(0.5, 25.0, 0.0), gate, 0.25, pred, t, idx, true[idx])
    gain = run_estimator(BiasGainKalman(0.5, 25.0, 0.0, "gain", s_sd=0.3), gate, 0.25, pred, t,
                         idx, true[idx])
    late = slice(4 * 60, None)  # after a few readings
    err_bias = np.sqrt(np.mean((true - pred - bias.correction)[late] ** 2))
    err_gain = np.sqrt(np.mean((true - pred - gain.correction)[late] ** 2))
    assert err_gain < 0.5 * err_bias, (err_gain, err_bias)
    assert gain.refused == 0

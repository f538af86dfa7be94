"""Nested validation and the ridge family (host.train.nested, .ridge_family; host.fitting.ridge).

Expectations are recomputed here with numpy and scikit-learn, never read back from the code.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from sklearn.linear_model import Ridge

from thermal_comp import codegen
from thermal_comp.contract.box import BOX_STATES
from thermal_comp.contract.terms import make_lag, make_rate, make_speed, make_temp
from thermal_comp.host.fitting import NO_REFERENCE, Reference, fit_ridge, fold_groups
from thermal_comp.host.io import Run
from thermal_comp.host.train import train_model
from thermal_comp.host.train.nested import (
    FoldTerms,
    NestedResult,
    fold_training,
    nested_validation,
    promise_from_folds,
    thinned,
)
from thermal_comp.host.train.ridge_family import ridge_basis, ridge_start, shared_lag_budget

PERIOD = 60.0


def _run(name: str, seed: int, n: int = 480) -> Run:
    rng = np.random.default_rng(seed)
    t = np.arange(n) * PERIOD
    rpm = np.where((t // 7200) % 2 == 0, 6000.0, 0.0)
    heat = np.cumsum(rpm / 6000.0 - 0.4) * 0.002
    t1 = 20 + heat + 0.02 * rng.standard_normal(n)
    t2 = 20 + 0.5 * np.convolve(heat, np.ones(30) / 30, "same") + 0.02 * rng.standard_normal(n)
    t3 = 20 + 0.3 * rng.standard_normal(n).cumsum() * 0.01
    dz = 3.0 * (t1 - t1[0]) - 1.5 * (t2 - t2[0]) + 0.1 * rng.standard_normal(n)
    return Run(name, t, ["T1", "T2", "T3"], np.column_stack([t1, t2, t3]), ["dz_um"],
               dz[:, None], ["spindle_rpm"], rpm[:, None])


def test_ridge_matches_scikit_learn_at_a_given_penalty():
    rng = np.random.default_rng(0)
    X = rng.normal(size=(300, 4)) * [1, 10, 0.1, 3] + 5
    y = X @ [1, 0.2, -3, 0.5] + 2 + rng.normal(size=300)
    fit = fit_ridge(X, y, np.repeat([0, 1, 2], 100), alphas=(0.1,))
    mu, sd = X.mean(0), X.std(0)
    ref = Ridge(alpha=0.1 * 300).fit((X - mu) / sd, y)  # per standardised column and sample
    np.testing.assert_allclose(fit.coef, ref.coef_ / sd, rtol=1e-9)
    assert fit.intercept == pytest.approx(ref.intercept_ - (mu / sd) @ ref.coef_, rel=1e-9)


def test_ridge_penalises_columns_of_one_unit_alike():
    rng = np.random.default_rng(1)
    X = rng.normal(size=(300, 4)) * [1, 10, 0.1, 3] + 5
    y = X @ [1, 0.2, -3, 0.5] + 2 + rng.normal(size=300)
    shared = [True, True, True, False]  # three columns in kelvin, one in rpm
    fit = fit_ridge(X, y, np.repeat([0, 1, 2], 100), alphas=(0.1,), shared=shared)
    mu, sd = X.mean(0), X.std(0)
    scale = sd.copy()
    scale[:3] = np.sqrt(np.mean(sd[:3] ** 2))
    ref = Ridge(alpha=0.1 * 300).fit((X - mu) / scale, y)
    np.testing.assert_allclose(fit.coef, ref.coef_ / scale, rtol=1e-9)
    # the narrow column (sd 0.1) is no longer cheap to weigh: it is shrunk far more
    own = fit_ridge(X, y, np.repeat([0, 1, 2], 100), alphas=(0.1,))
    assert abs(fit.coef[2]) < 0.5 * abs(own.coef[2])
    with pytest.raises(ValueError, match="3 flags for 4 columns"):
        fit_ridge(X, y, np.repeat([0, 1, 2], 100), shared=shared[:3])


def test_fold_training_cuts_one_run_around_the_held_out_block():
    run = _run("a", 1, n=90)
    groups, _ = fold_groups([run], 3)
    pieces = fold_training([run], groups, 1)  # the middle block out: what lies before and after
    assert [(p.time_s[0], p.time_s[-1]) for p in pieces] == [(0.0, 29 * PERIOD),
                                                              (60 * PERIOD, 89 * PERIOD)]
    assert len(fold_training([run], groups, 0)) == 1
    runs = [run, _run("b", 2, n=90)]
    assert [r.path for r in fold_training(runs, fold_groups(runs, 3)[0], 0)] == ["b"]


def test_nested_validation_is_refit_without_each_run_and_predicts_it():
    runs = [_run("a", 1), _run("b", 2), _run("c", 3)]
    terms = [make_temp("T1"), make_temp("T2")]
    seen = []

    def train_fold(sub):
        seen.append([r.path for r in sub])
        # with an "effect", the baseline, and no free channel read
        return FoldTerms(terms + [make_lag("T1", 1800.0, PERIOD)], terms, terms, [])

    res = nested_validation(runs, "dz_um", train_fold, aux=[], period_s=PERIOD, n_blocks=3,
                            reference=NO_REFERENCE, max_states=0)
    assert seen == [["b", "c"], ["a", "c"], ["a", "b"]]
    for k in range(3):  # least squares by numpy on the other two runs, predicting run k
        tr = [r for i, r in enumerate(runs) if i != k]
        A = np.column_stack([np.ones(sum(r.n_samples for r in tr)),
                             np.vstack([r.temperatures[:, :2] for r in tr])])
        beta = np.linalg.lstsq(A, np.concatenate([r.target("dz_um") for r in tr]), rcond=None)[0]
        pred = beta[0] + runs[k].temperatures[:, :2] @ beta[1:]
        expect = np.sqrt(np.mean((runs[k].target("dz_um") - pred) ** 2))
        assert res.fold_rmse_um["baseline"][k] == pytest.approx(expect, rel=1e-6)
    assert set(res.fold_rmse_um) == {"ols", "baseline", "ridge", "ridge-baseline"}
    assert all(len(v) == 3 for v in res.fold_rmse_um.values())
    assert res.rms("baseline") == pytest.approx(
        np.sqrt(np.mean(np.square(res.fold_rmse_um["baseline"]))))


def test_long_runs_are_judged_on_every_kth_sample():
    runs = [_run("a", 1), _run("b", 2), _run("c", 3)]  # 3 x 480 samples
    same, period = thinned(runs, PERIOD, max_rows=1440)
    assert period == PERIOD and [r.n_samples for r in same] == [480] * 3
    thin, period = thinned(runs, PERIOD, max_rows=1000)  # ceil(1440 / 1000) = 2
    assert period == 2 * PERIOD and [r.n_samples for r in thin] == [240] * 3
    assert [r.period_s for r in thin] == [2 * PERIOD] * 3
    np.testing.assert_array_equal(thin[1].temperatures, runs[1].temperatures[::2])


def test_nested_folds_of_long_runs_train_on_the_thinned_runs(monkeypatch):
    import thermal_comp.host.train.nested as nested

    monkeypatch.setattr(nested, "NESTED_MAX_ROWS", 1000)
    runs = [_run("a", 1), _run("b", 2), _run("c", 3)]
    terms = [make_temp("T1"), make_temp("T2")]
    seen = []

    def train_fold(sub):
        seen.append([(r.n_samples, r.period_s) for r in sub])
        return FoldTerms(terms, terms, terms, [])

    res = nested_validation(runs, "dz_um", train_fold, aux=[], period_s=PERIOD, n_blocks=3,
                            reference=NO_REFERENCE, max_states=0)
    assert seen == [[(240, 2 * PERIOD)] * 2] * 3
    # the held-out run is scored on the same samples: least squares on every 2nd sample
    tr = [r.every(2) for r in runs[1:]]
    A = np.column_stack([np.ones(480), np.vstack([r.temperatures[:, :2] for r in tr])])
    beta = np.linalg.lstsq(A, np.concatenate([r.target("dz_um") for r in tr]), rcond=None)[0]
    held = runs[0].every(2)
    pred = beta[0] + held.temperatures[:, :2] @ beta[1:]
    expect = np.sqrt(np.mean((held.target("dz_um") - pred) ** 2))
    assert res.fold_rmse_um["baseline"][0] == pytest.approx(expect, rel=1e-6)


def test_nested_folds_in_forked_processes_give_the_serial_folds_errors(monkeypatch):
    import thermal_comp.host.train.nested as nested

    runs = [_run("a", 1), _run("b", 2), _run("c", 3)]  # 1,440 samples in all
    terms = [make_temp("T1"), make_temp("T2")]
    asked = []
    real = nested.forked_map

    def recorded(work, items, desc, *, workers=None, quiet=True):
        asked.append(workers)
        return real(work, items, desc, workers=workers, quiet=quiet)

    def train_fold(sub):
        return FoldTerms(terms + [make_lag("T1", 1800.0, PERIOD)], terms, terms, [])

    monkeypatch.setattr(nested, "forked_map", recorded)
    kwargs = dict(aux=["spindle_rpm"], period_s=PERIOD, n_blocks=3, reference=NO_REFERENCE,
                  max_states=4)
    monkeypatch.setattr(nested, "PARALLEL_MIN_ROWS", 1441)  # too short: this process
    serial = nested_validation(runs, "dz_um", train_fold, **kwargs)
    monkeypatch.setattr(nested, "PARALLEL_MIN_ROWS", 1440)  # long enough: the usable cores
    forked = nested.nested_validation(runs, "dz_um", train_fold, **kwargs)
    one = nested.nested_validation(runs, "dz_um", train_fold, jobs=1, **kwargs)  # --jobs 1
    assert asked == [1, None, 1]
    assert forked.fold_rmse_um == serial.fold_rmse_um == one.fold_rmse_um
    assert all(len(v) == 3 and all(math.isfinite(x) for x in v)
               for v in forked.fold_rmse_um.values())


def test_jobs_reach_the_nested_folds_from_every_entry_and_do_not_change_the_model(
        monkeypatch, tmp_path, capsys):
    import thermal_comp.host.train.nested as nested
    from thermal_comp.host.cli import main
    from thermal_comp.host.io import write_run
    from thermal_comp.host.train import TrainingError
    from thermal_comp.host.train.estimator import ThermalModel

    asked = []
    real = nested.forked_map

    def recorded(work, items, desc, *, workers=None, quiet=True):
        asked.append(workers)
        return real(work, items, desc, workers=workers, quiet=quiet)

    monkeypatch.setattr(nested, "forked_map", recorded)
    monkeypatch.setattr(nested, "PARALLEL_MIN_ROWS", 1)  # every run is long enough
    runs = [_run("a", 1), _run("b", 2)]
    kw = dict(aux=["spindle_rpm"], effects=False, groups=2, max_sensors=2)
    default = train_model(runs, ["dz_um"], **kw)
    one = train_model(runs, ["dz_um"], jobs=1, **kw)
    assert asked == [None, 1]
    assert one == default  # the processes are how, not what
    for bad in (0, -1, 1.5, True):
        with pytest.raises(TrainingError, match="--jobs must be a number of processes"):
            train_model(runs, ["dz_um"], jobs=bad, **kw)
    X = np.vstack([r.temperatures for r in runs])
    X = np.column_stack([X, np.concatenate([r.aux[:, 0] for r in runs])])
    y = np.concatenate([r.target("dz_um") for r in runs])
    groups = np.repeat([0, 1], 480)
    asked.clear()
    for n_jobs in (None, -1, 2):
        ThermalModel(aux_names=["spindle_rpm"], period_s=PERIOD, effects=False, n_groups=2,
                     max_sensors=2, n_jobs=n_jobs).fit(X, y, groups)
    assert asked == [None, None, 2]  # -1 is scikit-learn's "every processor": the default
    csv = tmp_path / "a.csv"
    r = runs[0]
    write_run(csv, r.time_s, {"T1": r.temperatures[:, 0], "T2": r.temperatures[:, 1],
                              "T3": r.temperatures[:, 2], "spindle_rpm": r.aux[:, 0],
                              "dz_um": r.target("dz_um")})
    asked.clear()
    assert main(["train", str(csv), "--target", "dz_um", "--aux", "spindle_rpm",
                 "--no-effects", "--no-codegen", "--jobs", "1",
                 "--out", str(tmp_path / "m")]) == 0
    assert asked == [1]
    assert main(["train", str(csv), "--target", "dz_um", "--aux", "spindle_rpm",
                 "--no-effects", "--no-codegen", "--jobs", "0",
                 "--out", str(tmp_path / "m")]) == 2
    assert "--jobs must be a number of processes, 1 or more (got 0)" in capsys.readouterr().err


def test_ridge_basis_spends_only_the_states_it_is_given():
    terms = [make_temp("T1"), make_temp("T2")]
    full = ridge_basis(terms, ["spindle_rpm"], PERIOD, 8 * 3600.0, max_states=8)
    assert make_lag("T1", 900.0, PERIOD) in full and make_lag("T2", 3600.0, PERIOD) in full
    assert sum(t.kind == "lag" for t in full) == 4
    assert sum(t.kind == "lag" for t in ridge_basis(terms, [], PERIOD, 8 * 3600.0, 3)) == 2
    assert ridge_basis(terms, [], PERIOD, 8 * 3600.0, 1) == terms  # one state: no lag pair
    # a sensor read on a free channel: its temperature and its lags, as far as the states go
    also = ridge_basis(terms, [], PERIOD, 8 * 3600.0, 8, also=["T3", "T1"])
    assert also[:3] == [*terms, make_temp("T3")]
    assert also[3:] == [make_lag(s, tau, PERIOD) for tau in (900.0, 3600.0)
                        for s in ("T1", "T2", "T3")]
    assert ridge_basis(terms, [], PERIOD, 8 * 3600.0, 5, also=["T3"])[3:] == [
        make_lag(s, 900.0, PERIOD) for s in ("T1", "T2", "T3")]
    # a term's own lag is one of the pool's filters: it costs no second state
    own = [make_temp("T1"), make_lag("T1", 900.0, PERIOD)]
    assert sum(t.kind == "lag" for t in ridge_basis(own, [], PERIOD, 8 * 3600.0, 2)) == 2


def test_the_lag_pool_is_paid_for_once_over_every_axis():
    runs = [_run("a", 1)]  # 8 h: both time constants identified
    read = [f"T{i}" for i in range(1, 9)]  # eight wired sensors, two time constants: 16 states
    axes = [[make_temp("T1")], [make_temp("T2"), make_lag("T2", 900.0, PERIOD)],
            [make_temp("T3"), make_lag("T3", 7200.0, PERIOD)]]
    budget = shared_lag_budget(axes, read, runs, PERIOD)
    assert budget == {0: 16, 1: 16, 2: 17}  # the pool, plus the one lag outside it
    # an effect's own filters take room first: 20 distinct lags of T1 (one of them at 900 s,
    # the pool's) leave room for the pool's first time constant only: 20 + 8 - 1
    effects = [[make_lag("T1", 60.0 * (i + 1), PERIOD) for i in range(20)]]
    assert shared_lag_budget(effects, read, runs, PERIOD) == {0: 27}


def test_the_promise_comes_from_the_folds_and_the_rms_takes_every_fold():
    result = NestedResult("nested", {"ridge": [3.0, 1.0, 2.0], "baseline": []})
    assert result.promise("ridge") == promise_from_folds([3.0, 1.0, 2.0]) >= 2.0
    assert result.rms("ridge") == pytest.approx(math.sqrt(14.0 / 3.0))
    assert math.isnan(result.promise("baseline"))


def test_train_promises_a_nested_error_and_the_box_runs_either_family():
    runs = [_run("a", 1), _run("b", 2)]
    for fit in ("auto", "ridge"):
        model = train_model(runs, ["dz_um"], aux=["spindle_rpm"], effects=False, groups=3,
                            max_sensors=2, fit=fit, reference="start")
        axis = model["axes"]["dz_um"]
        assert axis["fit"]["requested"] == fit
        # the rule model.json states is the one that chose: only auto compares nested errors
        assert ("lowest nested error" in axis["fit"]["rule"]) == (fit == "auto")
        assert len(axis["metrics"]["promised_fold_rmse_um"]) == 2  # one per held-out run
        # the promise comes from the chosen family's folds (NestedResult.promise)
        folds = axis["fit"]["nested"]["fold_rmse_um"][axis["fit"]["family"]]
        assert axis["metrics"]["promised_fold_rmse_um"] == folds
        assert axis["metrics"]["promised_rmse_um"] == promise_from_folds(folds)
        states = sum(t["kind"] in ("lag", "rate") for t in axis["terms"])
        assert states <= BOX_STATES
        codegen.generate(model)  # the fixed-point bound holds for what was chosen
    assert axis["fit"]["family"] == "ridge" and states > 0
    assert Reference.of_model(model).kind == "start"


def test_a_dead_sensor_is_never_selected():
    """A thermocouple stuck at one value carries no signal (and a condition number of inf)."""
    runs = [_run("a", 1), _run("b", 2)]
    for r in runs:
        r.temperatures[:, 0] = 21.0  # T1, the strongest driver, is dead in training
    model = train_model(runs, ["dz_um"], effects=False, groups=3, max_sensors=2, fit="ols",
                        nested=False)
    assert "T1" not in {t.get("source") for t in model["axes"]["dz_um"]["terms"]}


def test_the_ridge_starts_without_the_filters_of_lag_and_rate_effects():
    slow = make_lag("T3", 7200.0, PERIOD)
    rate = make_rate("T2", 1800.0, PERIOD)
    speed = make_speed("spindle_rpm")
    terms = [make_temp("T1"), slow, rate, speed]
    effects = [{"kind": "lag", "added": [slow.to_json()]},
               {"kind": "rate", "added": [rate.to_json()]},
               {"kind": "speed", "added": [speed.to_json()]}]
    # the filters go, their sensors stay read (as temperatures), the speed effect stays
    assert ridge_start(terms, effects, 900.0) == [make_temp("T1"), speed, make_temp("T3"),
                                           make_temp("T2")]
    assert ridge_start(terms, effects[2:], 900.0) == terms
    # a lag of a sensor the terms already read costs nothing more than that sensor
    own = make_lag("T1", 900.0, PERIOD)
    assert ridge_start([make_temp("T1"), own], [{"kind": "lag", "added": [own.to_json()]}],
                       900.0) == [make_temp("T1")]
    # a lag faster than the ridge's fastest is not a blend of its lags: it stays
    fast = make_lag("T3", 300.0, PERIOD)
    assert ridge_start([make_temp("T1"), fast], [{"kind": "lag", "added": [fast.to_json()]}],
                       900.0) == [make_temp("T1"), fast]
    # a ridge without lags (runs too short for them) leaves every effect its own filter
    assert ridge_start(terms, effects, math.inf) == terms


def _bending_data(seed: int = 3, n: int = 600):
    """A column bent by its front against its back: the front (T1) and back (T2) warm
    together and the front a little more, the axis moves 17 um/K with their difference only."""
    rng = np.random.default_rng(seed)
    common = np.cumsum(rng.normal(0.01, 0.02, n))
    gradient = 0.2 * common + 0.05 * np.cumsum(rng.normal(0, 0.01, n))
    front, back = 20 + common + gradient, 20 + common
    other = 20 + 0.5 * common + 0.02 * rng.standard_normal(n)
    X = np.column_stack([front, back, other, rng.uniform(0, 8000, n)])
    y = 17.0 * (front - back) + 0.2 * rng.standard_normal(n)
    return X, y, np.repeat([0, 1, 2], n // 3)


def test_a_bending_axis_ridge_is_the_penalised_least_squares_it_claims_to_be():
    """Against an independent computation: the augmented least-squares problem of the same
    penalty, alpha n (|b|^2 + kappa (sum of the even columns' b)^2), on the scaled columns."""
    X, y, groups = _bending_data()
    shared, even = [True, True, True, False], [True, True, True, False]
    alpha, kappa, n = 0.01, 3.0, len(y)
    fit = fit_ridge(X, y, groups, alphas=(alpha,), shared=shared, even=even,
                    even_penalty=kappa)
    mu, sd = X.mean(0), X.std(0)
    scale = sd.copy()
    scale[:3] = np.sqrt(np.mean(sd[:3] ** 2))
    D = (X - mu) / scale
    s = np.array(even, dtype=float)
    A = np.vstack([D, math.sqrt(alpha * n) * np.eye(4), math.sqrt(alpha * n * kappa) * s])
    b = np.linalg.lstsq(A, np.concatenate([y - y.mean(), np.zeros(5)]), rcond=None)[0]
    np.testing.assert_allclose(fit.coef, b / scale, rtol=1e-8)
    assert fit.intercept == pytest.approx(y.mean() - (mu / scale) @ b, rel=1e-9)


def test_the_even_warming_penalty_shrinks_the_response_to_an_even_warming_as_it_grows():
    X, y, groups = _bending_data()
    shared = even = [True, True, True, False]
    plain = fit_ridge(X, y, groups, shared=shared)
    none = fit_ridge(X, y, groups, shared=shared, even=even, even_penalty=0.0)
    np.testing.assert_array_equal(none.coef, plain.coef)
    assert none.alpha == plain.alpha and none.intercept == plain.intercept
    sums = [abs(fit_ridge(X, y, groups, alphas=(0.1,), shared=shared, even=even,
                          even_penalty=k).coef[:3].sum()) for k in (0.0, 1.0, 3.0, 30.0)]
    assert sums == sorted(sums, reverse=True) and sums[-1] < 0.25 * sums[0]
    with pytest.raises(ValueError, match="3 flags for 4 columns"):
        fit_ridge(X, y, groups, shared=shared, even=even[:3], even_penalty=1.0)
    with pytest.raises(ValueError, match="must be shared"):  # the sum needs one unit
        fit_ridge(X, y, groups, shared=shared, even=[True, True, True, True],
                  even_penalty=1.0)


def test_train_shapes_only_the_bending_axis_ridge_and_says_so():
    from thermal_comp.host.train import TrainingError
    from thermal_comp.host.train.ridge_family import EVEN_WARMING_PENALTY

    base = _run("a", 1)
    t1, t2 = base.temperatures[:, 0], base.temperatures[:, 1]
    dy = 17.0 * ((t1 - t1[0]) - (t2 - t2[0]))
    run = Run("a", base.time_s, base.sensor_names, base.temperatures, ["dy_um", "dz_um"],
              np.column_stack([dy, base.displacements[:, 0]]), base.aux_names, base.aux)
    kw = dict(aux=["spindle_rpm"], effects=False, groups=3, max_sensors=3, nested=False)
    plain = train_model([run], ["dy_um", "dz_um"], **kw)
    bent = train_model([run], ["dy_um", "dz_um"], bending=["dy_um"], **kw)
    assert bent["training"]["bending"] == ["dy_um"]
    assert bent["axes"]["dy_um"]["fit"]["even_warming_penalty"] == EVEN_WARMING_PENALTY
    assert bent["axes"]["dz_um"]["fit"]["even_warming_penalty"] == 0.0
    assert bent["axes"]["dz_um"]["terms"] == plain["axes"]["dz_um"]["terms"]

    def even_response(model):  # um per kelvin of an even, settled warming
        return abs(sum(t["coef"] for t in model["axes"]["dy_um"]["terms"]
                       if t["kind"] in ("temp", "lag")))

    assert even_response(bent) < even_response(plain)
    with pytest.raises(TrainingError, match="--bending dx_um: not among the targets"):
        train_model([run], ["dy_um"], bending=["dx_um"], **kw)
    with pytest.raises(TrainingError, match="least squares has none"):
        train_model([run], ["dy_um"], bending=["dy_um"], fit="ols", **kw)
    with pytest.raises(TrainingError, match="least squares has none"):  # no folds: auto = ols
        train_model([run], ["dy_um"], bending=["dy_um"], fit="auto", **kw)


def test_a_bending_axis_kept_as_least_squares_does_not_claim_the_penalty(monkeypatch):
    import thermal_comp.host.train.nested as nested

    monkeypatch.setattr(nested.NestedResult, "rms",
                        lambda self, family: 0.0 if family == "ols" else 1.0)
    model = train_model([_run("a", 1), _run("b", 2)], ["dz_um"], aux=["spindle_rpm"],
                        effects=False, groups=3, max_sensors=2, fit="auto", bending=["dz_um"])
    fit = model["axes"]["dz_um"]["fit"]
    assert fit["family"] == "ols" and fit["even_warming_penalty"] == 0.0
    assert model["training"]["bending"] == ["dz_um"]  # what the user declared stays on record


def _speed_growth_run(name: str, seed: int, growth_um: float, n: int = 720) -> Run:
    """_run's machine at three spindle speeds, its dz growing with the speed's square at once
    (no thermocouple sees it; the ridge's basis has the speed, not its square)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * PERIOD
    rpm = np.array([6000.0, 0.0, 3000.0, 0.0, 4500.0, 0.0])[(t // 7200).astype(int) % 6]
    heat = np.cumsum(rpm / 6000.0 - 0.4) * 0.002
    t1 = 20 + heat + 0.02 * rng.standard_normal(n)
    t2 = 20 + 0.5 * np.convolve(heat, np.ones(30) / 30, "same") + 0.02 * rng.standard_normal(n)
    t3 = 20 + 0.3 * rng.standard_normal(n).cumsum() * 0.01
    dz = (3.0 * (t1 - t1[0]) - 1.5 * (t2 - t2[0]) + growth_um * (rpm / 6000.0) ** 2
          + 0.1 * rng.standard_normal(n))
    return Run(name, t, ["T1", "T2", "T3"], np.column_stack([t1, t2, t3]), ["dz_um"],
               dz[:, None], ["spindle_rpm"], rpm[:, None])


def _write_dz_runs(runs: list[Run], folder: Path) -> list[Path]:
    """The runs as CSV files for the CLI (temperatures, dz_um, spindle_rpm)."""
    from thermal_comp.host.io import write_run

    paths = []
    for run in runs:
        cols = {n: run.temperatures[:, i] for i, n in enumerate(run.sensor_names)}
        cols.update({"dz_um": run.displacements[:, 0], "spindle_rpm": run.aux[:, 0]})
        paths.append(folder / f"{run.path}.csv")
        write_run(paths[-1], run.time_s, cols)
    return paths


def test_the_box_models_error_without_and_with_its_effects_is_reported(tmp_path, capsys):
    """The loop's before/after on the model the box runs: its family refitted on the nested
    folds with the effects and without them. A speed growth the basis lacks must show there."""
    import json

    from thermal_comp.host.cli import main
    from thermal_comp.host.train import box_effects_evidence

    runs = [_speed_growth_run("a", 1, 4.0), _speed_growth_run("b", 2, 4.0)]
    model = train_model(runs, ["dz_um"], aux=["spindle_rpm"], groups=3, max_sensors=2,
                        reference="start")
    axis = model["axes"]["dz_um"]
    assert any(e["kind"] == "speed" for e in axis["effects"])
    evidence = box_effects_evidence(axis)
    folds = axis["fit"]["nested"]["fold_rmse_um"]
    assert axis["fit"]["family"] == "ridge"
    # the RMS over the held-out runs of the box's family with and without its effects
    assert evidence["with_effects"] == pytest.approx(np.sqrt(np.mean(np.square(folds["ridge"]))))
    assert evidence["without_effects"] == pytest.approx(
        np.sqrt(np.mean(np.square(folds["ridge-baseline"]))))
    # 4 um of growth at full speed, 0.1 um of gauge noise: the effect is most of the error
    assert evidence["with_effects"] < 0.3 * evidence["without_effects"]
    # without the growth nothing is added and nothing is claimed
    clean = train_model([_speed_growth_run("a", 1, 0.0), _speed_growth_run("b", 2, 0.0)],
                        ["dz_um"], aux=["spindle_rpm"], groups=3, max_sensors=2,
                        reference="start")
    assert not clean["axes"]["dz_um"].get("effects")
    assert box_effects_evidence(clean["axes"]["dz_um"]) is None
    # host train prints it beside the search's least squares, and --json carries it
    paths = _write_dz_runs(runs, tmp_path)
    train = ["train", *map(str, paths), "--target", "dz_um", "--aux", "spindle_rpm",
             "--groups", "3", "--max-sensors", "2", "--no-codegen"]
    assert main([*train, "--out", str(tmp_path / "text")]) == 0
    printed = capsys.readouterr().out
    line = next(x for x in printed.splitlines() if "the box's model on the nested folds" in x)
    assert "without the effects" in line and "with them" in line
    assert main([*train, "--out", str(tmp_path / "json"), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    box = doc["axes"]["dz_um"]["box_nested_rmse_um"]
    assert box["families"] == ["ridge", "ridge-baseline"]
    assert box["with_effects"] < 0.3 * box["without_effects"]


def _slow_path_run(name: str, seed: int, n: int = 960) -> Run:
    """A machine whose dz follows T1 at once and through a slow path (a 1-h first-order lag of
    T1, as a column warming behind its skin): the ridge's own lags of T1 cover that path."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * PERIOD
    rpm = np.array([6000.0, 0.0, 3000.0, 0.0])[(t // 10800).astype(int) % 4]
    t1 = 20 + np.cumsum(rpm / 6000.0 - 0.45) * 0.004 + 0.02 * rng.standard_normal(n)
    slow = np.empty(n)
    slow[0] = t1[0]
    k = PERIOD / 3600.0
    for i in range(1, n):
        slow[i] = slow[i - 1] + k * (t1[i] - slow[i - 1])
    t2 = 20 + 0.3 * rng.standard_normal(n).cumsum() * 0.01
    dz = 2.0 * (t1 - t1[0]) + 6.0 * (slow - slow[0]) + 0.05 * rng.standard_normal(n)
    return Run(name, t, ["T1", "T2"], np.column_stack([t1, t2]), ["dz_um"], dz[:, None],
               ["spindle_rpm"], rpm[:, None])


def test_an_effect_the_box_ridge_already_covers_is_named_and_not_run(tmp_path, capsys):
    """The search names the slow path on least squares over the selected terms, but the box's
    ridge reads the lags of T1 already: it is not 10 % lower with the effect, so the box runs
    the ridge trained without effects, the effect stays listed with why, and host train says so."""
    from thermal_comp.host.cli import main

    runs = [_slow_path_run("a", 1), _slow_path_run("b", 2)]
    kw = dict(aux=["spindle_rpm"], groups=2, max_sensors=2, reference="start", nested=False)
    axis = train_model(runs, ["dz_um"], **kw)["axes"]["dz_um"]
    assert any(e["kind"] in ("lag", "rate") for e in axis["effects"])
    assert axis["fit"]["family"] == "ridge-baseline"
    assert all(e["dropped_by_box_ridge"] for e in axis["effects"])
    assert "they must lower it by 10 %" in axis["effects_rejected"]
    plain = train_model(runs, ["dz_um"], effects=False, **kw)["axes"]["dz_um"]
    assert plain["fit"]["family"] == "ridge"
    assert axis["terms"] == plain["terms"] and axis["intercept"] == plain["intercept"]
    paths = _write_dz_runs(runs, tmp_path)
    assert main(["train", *map(str, paths), "--target", "dz_um", "--aux", "spindle_rpm",
                 "--groups", "2", "--max-sensors", "2", "--no-codegen", "--no-nested",
                 "--out", str(tmp_path / "m")]) == 0
    printed = capsys.readouterr().out
    assert "dz_um: the box's model runs without the effects: its ridge is" in printed
    assert "DROPPED: the box's ridge is not 10 % lower" in printed


def test_nested_validation_gives_the_promise_not_the_model():
    """The model the box runs is the same with and without nested validation (it only adds the
    promise): what bench.quick_accuracy, which trains without it, rests on."""
    runs = [_run("a", 1), _run("b", 2)]
    kw = dict(aux=["spindle_rpm"], groups=3, max_sensors=3, reference="start")
    with_nested = train_model(runs, ["dz_um"], **kw)["axes"]["dz_um"]
    without = train_model(runs, ["dz_um"], nested=False, **kw)["axes"]["dz_um"]
    assert "promised_rmse_um" in with_nested["metrics"]
    assert "promised_rmse_um" not in without["metrics"]
    assert with_nested["fit"]["family"] == without["fit"]["family"] == "ridge"
    assert with_nested["terms"] == without["terms"]
    assert with_nested["intercept"] == without["intercept"]

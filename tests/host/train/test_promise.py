"""The promise (issue 43): one figure with a stated coverage, never below the median fold,
written the same in model.json, ``host train`` and the report, and holding on machines no
calibration saw (tests/data/promise_heldout.json: bench.bench_promise --heldout)."""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path

import numpy as np
import pytest
from test_next_day import _run  # the same two-sensor runs the nested validation tests use

from bench import bench_promise as bp
from thermal_comp.host.io import write_run
from thermal_comp.host.train import summary, train_model
from thermal_comp.host.train.nested import (
    PROMISE_COVERAGE,
    PROMISE_FACTOR,
    PROMISE_TAIL,
    NestedResult,
    promise_from_folds,
    promise_statement,
)

DATA = Path(__file__).resolve().parents[2] / "data"
COVERAGE_WORDS = f"on {100 * PROMISE_COVERAGE:.0f} % of days"


@pytest.fixture(scope="module")
def model() -> dict:
    return train_model([_run("a", 1), _run("b", 2)], ["dz_um"], aux=["spindle_rpm"],
                       effects=False, groups=3, max_sensors=2, reference="start")


@pytest.mark.parametrize("folds", [[1.0], [1.0, 2.0], [3.0, 1.0, 2.0], [0.2, 0.2, 9.0],
                                   [5.0, 0.1, 0.1, 0.1]])
def test_the_promise_is_never_below_the_median_fold(folds):
    assert promise_from_folds(folds) >= float(np.median(folds))
    assert PROMISE_FACTOR >= 1.0
    result = NestedResult("nested", {"ridge": folds, "baseline": []})
    assert result.promise("ridge") == promise_from_folds(folds)
    assert math.isnan(result.promise("baseline"))


def test_the_statement_names_the_figure_and_its_coverage():
    assert promise_statement(3.14159, "dz_um") == "RMS on an unseen day ≤ 3.14 µm on 80 % of days"
    assert promise_statement(2.0, "a_urad").endswith("2.00 µrad on 80 % of days")


def test_model_json_and_host_train_json_state_the_promise_and_its_coverage(model):
    m = model["axes"]["dz_um"]["metrics"]
    folds = m["promised_fold_rmse_um"]
    assert m["promised_rmse_um"] == promise_from_folds(folds)
    assert m["promised_rmse_um"] >= float(np.median(folds))
    assert m["promised_coverage"] == PROMISE_COVERAGE
    assert m["promise"] == promise_statement(m["promised_rmse_um"], "dz_um")
    assert COVERAGE_WORDS in m["promise"]
    doc = summary(model, "model.json")["axes"]["dz_um"]  # host train --json
    assert doc["promised_rmse_um"] == m["promised_rmse_um"]
    assert doc["promise"] == m["promise"]


def test_the_report_states_the_promise_with_its_coverage(model, tmp_path):
    from thermal_comp.contract.model_file import write_model
    from thermal_comp.host.analysis.report import build_report

    path = tmp_path / "model.json"
    write_model(copy.deepcopy(model), path)
    runs = []
    for run in (_run("c", 3),):  # a day the model never saw
        csv = tmp_path / f"{run.name}.csv"
        write_run(csv, run.time_s, {**dict(zip(run.sensor_names, run.temperatures.T,
                                               strict=True)),
                                    "spindle_rpm": run.aux[:, 0],
                                    "dz_um": run.displacements[:, 0]})
        runs.append(csv)
    build_report(path, runs, tmp_path / "report", peers=False, quiet=True)
    page = (tmp_path / "report" / "index.html").read_text()
    assert model["axes"]["dz_um"]["metrics"]["promise"] in page


def test_the_calibration_rule_finds_the_smallest_factor_and_can_fail():
    # ten days at 1..10 x their statistic: 80 % at or below 8, none above 2 x 8
    ratios = [float(k) for k in range(1, 11)]
    assert bp.needed_factor(ratios, 0.8, 0.05) == 8.0
    # one day at 40x: more than 5 % above twice 8, so the tail sets the factor
    assert bp.needed_factor([*ratios[:9], 40.0], 0.8, 0.05) == 20.0
    case = bp.PromiseCase("s", "g", "g", "t", "dz_um", 1.0, [0.5], "ridge", "runs")
    assert not bp.holds(bp.coverage([case], [0.9]))  # 1.0 > 0.9: below the coverage
    assert bp.holds(bp.coverage([case], [1.0]))


def test_the_promise_holds_on_machines_no_calibration_saw():
    """The held-out machines (the project's simulator, seeds bench_promise.HELDOUT_SEEDS,
    trained as the accuracy bench's sim jobs): at least the stated share of their unseen days
    at or below host train's promise, at most PROMISE_TAIL above twice it. Fails when the
    promise's rule or factor loses its coverage; after a change to the model, regenerate the
    cases (python -m bench.bench_promise --heldout) and look at this again."""
    cases = bp.usable([bp.PromiseCase(**d) for d in
                       json.loads((DATA / "promise_heldout.json").read_text())["cases"]])
    assert len(cases) >= 12
    cov = bp.coverage(cases, [promise_from_folds(c.folds_um) for c in cases])
    assert cov["at or below"] >= PROMISE_COVERAGE, cov
    assert cov["above twice"] <= PROMISE_TAIL, cov
    # the old promise (the lowest fold) did not: the check can fail
    old = bp.coverage(cases, [min(c.folds_um) for c in cases])
    assert old["at or below"] < PROMISE_COVERAGE


def test_the_accuracy_bench_reports_the_coverage_per_source():
    from bench import bench_accuracy as acc

    cases = []
    for test, promised in ((1.0, 1.5), (4.0, 1.0), (0.5, 1.0), (1.0, 1.0)):
        c = acc.CaseResult("fl", "g", "t", "ch1_um", "none")
        c.rmse_um = {"default": test, "no effects": test, "paper": test, "OLS all": 1.0}
        c.promised_um = {"default": promised}
        cases.append(c)
    cal = acc.summarise(cases)["calibration"]["fl"]
    assert cal["fraction at or below the promise"] == 0.75  # 1.0 / 1.0 counts as kept
    assert cal["fraction above twice the promise"] == 0.25  # 4 µm where 1 promised
    text = acc.table(cases, acc.summarise(cases))
    assert "<= promise" in text and "> 2x promise" in text


def test_the_promise_holds_on_every_dev_source_it_was_calibrated_on():
    """The saved calibration cases (bench/data/promise_cases.json, python -m bench promise):
    host train's promise keeps its coverage on each source, not only on all of them pooled."""
    cases = bp.usable(bp.load(bp.SAVED))
    for source in bp.SOURCES:
        mine = [c for c in cases if c.source == source]
        cov = bp.coverage(mine, [promise_from_folds(c.folds_um) for c in mine])
        assert len(mine) >= 18 and bp.holds(cov), (source, cov)

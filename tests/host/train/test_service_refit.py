"""`host train --service LOG.csv` (host/train/service_refit.py): the trained terms refitted to
logged probe readings. Expectations come from how the data were made (the true gains), not
from the refit's own output."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from thermal_comp.contract.terms import make_temp
from thermal_comp.hil.example_model import fit_example_model
from thermal_comp.host.io import load_run, write_run
from thermal_comp.host.train.service_refit import (
    ServiceLogError,
    load_service_logs,
    refit_on_probes,
)

N, PERIOD = 600, 60.0
TRUE = (2.0, 0.0)  # um/degC of T1 and T2: only T1 moves the tool


def day(rng, together: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """T1, T2 and the displacement: on the training day T2 follows T1 (the fit cannot tell
    them apart); in service T2 has a life of its own."""
    t = np.arange(N) * PERIOD
    t1 = 20 + 8 * (1 - np.exp(-t / 7200)) + 0.3 * np.sin(t / 900)
    if together:
        t2 = t1 + rng.normal(0, 0.01, N)
    else:
        t2 = 20 + 6 * np.sin(t / 5000 + rng.uniform(0, 3)) ** 2
    return t1, t2, TRUE[0] * (t1 - 20) + TRUE[1] * (t2 - 20) + rng.normal(0, 0.05, N)


def write_log(path, t1, t2, y, every: int, rng) -> None:
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["time_s", "T1", "T2", "probe_dz_um"])
        for k in range(N):
            reading = f"{y[k] + rng.normal(0, 0.5):.4f}" if k and k % every == 0 else ""
            w.writerow([f"{k * PERIOD:g}", f"{t1[k]:.4f}", f"{t2[k]:.4f}", reading])


@pytest.fixture
def trained(tmp_path):
    rng = np.random.default_rng(3)
    t1, t2, y = day(rng, together=True)
    train = tmp_path / "train.csv"
    write_run(train, np.arange(N) * PERIOD, {"T1": t1, "T2": t2, "dz_um": y})
    model = fit_example_model(train, {"dz_um": [make_temp("T1"), make_temp("T2")]})
    # the training day cannot tell T1 from T2: any split of the gain fits it; take an even one,
    # as a ridge would (its intercept refitted on the day)
    terms = model["axes"]["dz_um"]["terms"]
    terms[0]["coef"] = terms[1]["coef"] = sum(TRUE) / 2
    model["axes"]["dz_um"]["intercept"] = float(np.mean(y - (t1 + t2) * sum(TRUE) / 2))
    return model, load_run(train, ["dz_um"], ["T1", "T2"]), rng


def gains(model: dict) -> np.ndarray:
    return np.array([t["coef"] for t in model["axes"]["dz_um"]["terms"]])


def test_readings_on_days_that_separate_the_sensors_recover_the_true_gains(trained, tmp_path):
    model, run, rng = trained
    assert abs(gains(model)[1] - TRUE[1]) > 0.9  # the training day left the split loose
    logs = []
    for k in range(4):
        t1, t2, y = day(rng, together=False)
        write_log(tmp_path / f"log{k}.csv", t1, t2, y, every=60, rng=rng)
        logs.append(tmp_path / f"log{k}.csv")
    t1, t2, y = day(rng, together=False)  # a test day no reading came from
    before = gains(model).copy()
    refit = refit_on_probes(model, [run], load_service_logs(logs, model))
    record = refit["axes"]["dz_um"]["service_refit"]
    assert record["refitted"] and record["readings"] == 4 * 9
    assert np.allclose(gains(refit), TRUE, atol=0.15), gains(refit)
    def miss(g: np.ndarray) -> float:  # on the test day, up to the datum a ZERO sets
        return float(np.std((g[0] - TRUE[0]) * t1 + (g[1] - TRUE[1]) * t2))

    assert miss(gains(refit)) < 0.3 * miss(before)


def test_readings_the_model_already_explains_leave_it_as_trained(trained, tmp_path):
    model, run, rng = trained
    logs = []
    for k in range(3):
        t1, t2, y = day(rng, together=True)  # days like the training day: nothing new
        write_log(tmp_path / f"log{k}.csv", t1, t2, y, every=60, rng=rng)
        logs.append(tmp_path / f"log{k}.csv")
    before = gains(model).copy()
    refit = refit_on_probes(model, [run], load_service_logs(logs, model))
    record = refit["axes"]["dz_um"]["service_refit"]
    assert not record["refitted"] and "trained model kept" in record["why"]
    assert np.array_equal(gains(refit), before)


def test_a_log_without_readings_is_refused_by_name(trained, tmp_path):
    model, _, rng = trained
    t1, t2, y = day(rng, together=False)
    log = tmp_path / "quiet.csv"
    write_log(log, t1, t2, y, every=10 * N, rng=rng)  # no touch in the whole log
    with pytest.raises(ServiceLogError, match=r"quiet\.csv: no probe readings.*probe_<axis>"):
        load_service_logs([log], model)


def test_a_log_at_another_sample_period_is_refused(trained, tmp_path):
    model, _, rng = trained
    log = tmp_path / "fast.csv"
    t1, t2, y = day(rng, together=False)
    write_log(log, t1, t2, y, every=60, rng=rng)
    text = log.read_text().splitlines()
    rows = [text[0]] + [f"{k * PERIOD / 2:g}," + line.split(",", 1)[1]
                        for k, line in enumerate(text[1:])]
    log.write_text("\n".join(rows) + "\n")
    with pytest.raises(ServiceLogError, match=r"fast\.csv: sample period 30 s, the model's is 60"):
        load_service_logs([log], model)


def test_one_log_cannot_be_judged_so_the_trained_model_stays(trained, tmp_path):
    import json

    model, run, rng = trained
    t1, t2, y = day(rng, together=False)  # a day that would teach the split
    write_log(tmp_path / "only.csv", t1, t2, y, every=60, rng=rng)
    before = gains(model).copy()
    refit = refit_on_probes(model, [run], load_service_logs([tmp_path / "only.csv"], model))
    record = refit["axes"]["dz_um"]["service_refit"]
    assert not record["refitted"] and record["why"].startswith("one log only")
    assert np.array_equal(gains(refit), before)
    json.dumps(record, allow_nan=False)  # model.json holds it: no inf, no nan

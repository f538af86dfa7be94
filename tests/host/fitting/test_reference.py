"""The ``start`` reference: a day that starts warmer than training is no offset."""

from __future__ import annotations

import numpy as np
import pytest

from thermal_comp.host.analysis import evaluate_model
from thermal_comp.host.fitting import Reference, causal_reference
from thermal_comp.host.io import Run
from thermal_comp.host.train import train_model

PERIOD = 60.0


def _day(seed: int, warm_k: float, n: int = 600) -> Run:
    """A heating day: the probes are zeroed at the start (dz = 0 at sample 0); the machine's
    drift is 2 um/K of T1's and 1 um/K of T2's change since then, plus probe noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * PERIOD
    heat = 1.0 - np.exp(-t / 7200.0)
    t1 = 20.0 + warm_k + 6.0 * heat + 0.02 * rng.standard_normal(n)
    t2 = 20.0 + warm_k + 3.0 * heat ** 2 + 0.02 * rng.standard_normal(n)
    t3 = 20.0 + warm_k + 0.5 * np.sin(t / 5000.0) + 0.02 * rng.standard_normal(n)
    dz = 2.0 * (t1 - t1[0]) + 1.0 * (t2 - t2[0]) + 0.1 * rng.standard_normal(n)
    dz -= dz[0]
    return Run(f"day{seed}.csv", t, ["T1", "T2", "T3"], np.column_stack([t1, t2, t3]),
               ["dz_um"], dz[:, None])


def test_causal_reference_is_the_running_mean_of_the_first_samples():
    x = np.array([4.0, 2.0, 6.0, 100.0, -5.0])
    # by hand: 4, (4+2)/2, (4+2+6)/3, then frozen at the mean of the first three
    np.testing.assert_allclose(causal_reference(x, 3), [4.0, 3.0, 4.0, 4.0, 4.0])
    np.testing.assert_allclose(Reference("start", 3).apply(x), [0.0, -1.0, 2.0, 96.0, -9.0])
    np.testing.assert_allclose(Reference("none").apply(x), x)
    # two runs stacked: each is referenced at its own start
    seg = np.array([0, 0, 0, 1, 1])
    np.testing.assert_allclose(Reference("start", 2).apply(x, seg), [0.0, -1.0, 3.0, 0.0, -52.5])


def test_window_is_the_box_zero_window():
    import re
    from pathlib import Path

    cfg = (Path(__file__).resolve().parents[3] / "firmware/include/box_config.h").read_text()
    box = int(re.search(r"#define BOX_ZERO_SAMPLES (\d+)", cfg).group(1))
    assert Reference.of_kind("start").samples == box
    assert Reference.of_kind("none").samples == 1
    with pytest.raises(ValueError, match="--reference"):
        Reference("tomorrow")


def test_a_warmer_day_gives_no_offset_with_start_and_one_without():
    train = [_day(1, 0.0), _day(2, 0.5)]
    test = _day(3, 3.0)  # starts 3 K warmer than training: 9 um of offset without a reference
    start = train_model(train, ["dz_um"], effects=False, groups=3, max_sensors=2,
                        reference="start", fit="ols", nested=False)
    none = train_model(train, ["dz_um"], effects=False, groups=3, max_sensors=2,
                       reference="none", fit="ols", nested=False)
    assert start["reference"] == {"kind": "start", "samples": 8}
    assert none["reference"] == {"kind": "none"}
    e_start = evaluate_model(start, test)["axes"]["dz_um"]["rmse_um"]
    e_none = evaluate_model(none, test)["axes"]["dz_um"]["rmse_um"]
    assert e_start < 0.5, e_start  # probe noise and the reference window's noise
    assert e_none > 2.0 and e_none > 8 * e_start, (e_none, e_start)  # a warmer day: offset
    # the same model judged by the other reference, on request
    assert evaluate_model(none, test, reference="start")["axes"]["dz_um"]["rmse_um"] < 0.5

"""The whole model as a scikit-learn estimator: the same model as `host train` on the same
data, predictions written out by hand, runs restarting the filters, a Pipeline, and the header
reached from Python (codegen.export_to_c)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from direct_fits import direct_lag
from sklearn.pipeline import Pipeline
from sklearn.preprocessing import FunctionTransformer

from thermal_comp import codegen
from thermal_comp.host.io import load_run
from thermal_comp.host.train import train_model
from thermal_comp.host.train.estimator import ThermalModel

ROOT = Path(__file__).resolve().parents[3]
RUN = ROOT / "examples" / "sim_constant.csv"


@pytest.fixture(scope="module")
def data():
    run = load_run(RUN, ["dz_um"])
    return run, run.temperatures, run.target("dz_um")


lag = direct_lag  # written out as a loop, independent of host.fitting


def by_hand(model: dict, axis_name: str, run) -> np.ndarray:
    """The model's output on a run, from its terms, with the start reference of docs/training.md:
    minus the running mean of the first k outputs, frozen after them."""
    axis = model["axes"][axis_name]
    out = np.full(run.n_samples, float(axis["intercept"]))
    for t in axis["terms"]:
        x = run.column(t["source"])
        if t["kind"] == "temp":
            feature = x
        elif t["kind"] == "lag":
            feature = lag(x, t["alpha"])
        elif t["kind"] == "rate":
            feature = x - lag(x, t["alpha"])
        else:
            assert t["kind"] == "square", t
            feature = (x - t["ref_c"]) ** 2
        out += t["coef"] * feature
    ref = model.get("reference") or {"kind": "none"}
    if ref["kind"] == "start":
        k = int(ref["samples"])
        head = np.cumsum(out[:k]) / np.arange(1, k + 1)
        out = out - np.r_[head, np.full(len(out) - k, head[-1])]
    return out


def test_same_model_as_host_train_and_predictions_by_hand(data):
    run, X, y = data
    est = ThermalModel(sensor_names=run.sensor_names, target_names=["dz_um"],
                       period_s=run.period_s, effects=False).fit(X, y)
    direct = train_model([RUN], ["dz_um"], effects=False)
    assert est.model_["axes"]["dz_um"]["terms"] == direct["axes"]["dz_um"]["terms"]
    model = est.to_model_json()
    np.testing.assert_allclose(est.predict(X), by_hand(model, "dz_um", run), rtol=1e-10,
                               atol=1e-9)
    assert est.score(X, y - y[0]) > 0.9 or est.score(X, y) > 0.9


def test_effect_terms_restart_with_each_run(data):
    run, X, y = data
    est = ThermalModel(sensor_names=run.sensor_names, period_s=run.period_s,
                       max_sensors=3).fit(X, y)
    assert est.model_["axes"]["y"]["terms"], "no term at all"
    half = len(y) // 2
    groups = np.r_[np.zeros(half, int), np.ones(len(y) - half, int)]
    both = est.predict(X, groups=groups)
    np.testing.assert_allclose(both[:half], est.predict(X[:half]))
    np.testing.assert_allclose(both[half:], est.predict(X[half:]))  # filters start afresh


def test_in_a_pipeline_and_on_to_the_box(data):
    run, X, y = data
    kelvin = X + 273.15
    pipe = Pipeline([("to_celsius", FunctionTransformer(lambda k: k - 273.15)),
                     ("model", ThermalModel(sensor_names=run.sensor_names, effects=False,
                                            period_s=run.period_s, max_sensors=3))])
    pipe.fit(kelvin, y)
    alone = ThermalModel(sensor_names=run.sensor_names, effects=False, period_s=run.period_s,
                         max_sensors=3).fit(X, y)
    np.testing.assert_allclose(pipe.predict(kelvin), alone.predict(X), atol=1e-6)
    # the same sensors and terms (the Kelvin round trip moves the data by float rounding only)
    assert [t["source"] for t in pipe.named_steps["model"].model_["axes"]["y"]["terms"]] == \
        [t["source"] for t in alone.model_["axes"]["y"]["terms"]]
    header = codegen.export_to_c(pipe.named_steps["model"])
    assert header == codegen.generate(pipe.named_steps["model"].to_model_json()).text
    assert "#define" in header
    # the whole Pipeline: its converter cannot be told from a scaler, so it is refused, named
    with pytest.raises(ValueError, match=r"\(FunctionTransformer\).*export_to_c\(pipeline\[-1\]\)"):
        codegen.export_to_c(pipe)


def test_bad_shapes_are_refused(data):
    run, X, y = data
    with pytest.raises(ValueError, match="sensor_names has 2 names"):
        ThermalModel(sensor_names=["a", "b"]).fit(X, y)
    with pytest.raises(ValueError, match="not contiguous"):
        ThermalModel(effects=False).fit(X, y, groups=np.arange(len(y)) % 2)


def test_the_fit_family_and_the_free_channels_are_estimator_parameters(data):
    run, X, y = data
    kw = dict(sensor_names=run.sensor_names, target_names=["dz_um"], period_s=run.period_s,
              effects=False, max_sensors=2)
    for family, fill in (("ols", True), ("ridge", False), ("ridge", True)):
        est = ThermalModel(**kw, family=family, fill_channels=fill).fit(X, y)
        direct = train_model([RUN], ["dz_um"], effects=False, max_sensors=2, fit=family,
                             fill_channels=fill)
        assert est.model_["axes"]["dz_um"]["terms"] == direct["axes"]["dz_um"]["terms"]
        assert est.model_["axes"]["dz_um"]["fit"]["family"] == family
        # only the ridge with the fill reads more than the two selected sensors
        assert (len(est.sensors_) > 2) is (family == "ridge" and fill)
    assert ThermalModel().get_params()["family"] == "ridge"


def test_a_bending_axis_is_an_estimator_parameter_as_in_host_train(data):
    run, X, y = data
    kw = dict(sensor_names=run.sensor_names, target_names=["dz_um"], period_s=run.period_s,
              effects=False, max_sensors=2)
    est = ThermalModel(**kw, bending=("dz_um",)).fit(X, y)
    direct = train_model([RUN], ["dz_um"], effects=False, max_sensors=2, bending=["dz_um"])
    plain = train_model([RUN], ["dz_um"], effects=False, max_sensors=2)
    assert est.model_["axes"]["dz_um"]["terms"] == direct["axes"]["dz_um"]["terms"]
    assert est.model_["axes"]["dz_um"]["terms"] != plain["axes"]["dz_um"]["terms"]
    assert ThermalModel().get_params()["bending"] == ()


class Frame:
    """A DataFrame stand-in (pandas is no dependency): an array with named ``columns``."""

    def __init__(self, data: np.ndarray, columns: list[str]) -> None:
        self._data = np.asarray(data, dtype=float)
        self.columns = list(columns)
        self.shape = self._data.shape

    def __array__(self, dtype=None, copy=None):
        return self._data if dtype is None else self._data.astype(dtype)

    def __len__(self) -> int:
        return len(self._data)


class Series:
    def __init__(self, data: np.ndarray, name: str) -> None:
        self._data, self.name, self.shape = np.asarray(data, dtype=float), name, np.shape(data)

    def __array__(self, dtype=None, copy=None):
        return self._data if dtype is None else self._data.astype(dtype)

    def __len__(self) -> int:
        return len(self._data)


def test_column_names_reach_model_json_and_the_wiring_sheet(data):
    from thermal_comp.host.analysis.metrology import wiring_rows

    run, X, y = data
    names = [f"spot_{i:02d}" for i in range(X.shape[1])]
    rpm = load_run(RUN, ["dz_um"], aux=["spindle_rpm"]).aux[:, 0]
    # the aux column in the middle: picked by its name, not its position
    frame = Frame(np.column_stack([X[:, :3], rpm, X[:, 3:]]),
                  names[:3] + ["spindle_rpm"] + names[3:])
    est = ThermalModel(aux_names=["spindle_rpm"], period_s=run.period_s, effects=False,
                       max_sensors=3).fit(frame, Series(y, "dz_um"))
    model = est.to_model_json()
    assert est.axes_ == ["dz_um"] and list(model["axes"]) == ["dz_um"]
    sensors = [c["sensor"] for c in model["channels"]]
    assert sensors and set(sensors) <= set(names), sensors
    assert {r["sensor"] for r in wiring_rows(model)} >= set(sensors)
    # the same model as the plain arrays with the names given by hand
    ordered = np.column_stack([X, rpm])  # temperatures first, then the aux input
    plain = ThermalModel(sensor_names=names, aux_names=["spindle_rpm"], target_names=["dz_um"],
                         period_s=run.period_s, effects=False, max_sensors=3).fit(ordered, y)
    assert model["axes"]["dz_um"]["terms"] == plain.model_["axes"]["dz_um"]["terms"]
    np.testing.assert_allclose(est.predict(frame), plain.predict(ordered), atol=1e-9)


def test_a_pipeline_exports_when_nothing_transforms_and_refuses_a_scaler(data):
    from sklearn.linear_model import LinearRegression
    from sklearn.preprocessing import StandardScaler

    run, X, y = data
    kw = dict(sensor_names=run.sensor_names, effects=False, period_s=run.period_s,
              max_sensors=3)
    plain = Pipeline([("nothing", "passthrough"), ("model", ThermalModel(**kw))]).fit(X, y)
    assert codegen.export_to_c(plain) == codegen.export_to_c(plain[-1])
    scaled = Pipeline([("scale", StandardScaler()), ("model", ThermalModel(**kw))]).fit(X, y)
    with pytest.raises(ValueError, match=r"transforms the inputs before the thermal model "
                       r"\(StandardScaler\).*neither dropped nor folded"):
        codegen.export_to_c(scaled)
    # the model step alone, fitted on the scaler's output, is refused too: never exported
    # as if the box fed it what the scaler made
    with pytest.raises(ValueError, match="look standardised"):
        codegen.export_to_c(scaled[-1])
    with pytest.raises(codegen.CodegenError, match="ends in LinearRegression"):
        codegen.export_to_c(Pipeline([("lr", LinearRegression())]).fit(X, y))

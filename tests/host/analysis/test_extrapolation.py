"""Training ranges in model.json, and the inputs of a new run that leave them (host evaluate,
host diagnose); every number recomputed with numpy from the CSV files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from thermal_comp.contract.model_file import ModelFormatError, read_model
from thermal_comp.host.analysis import diagnose, evaluate_model, summary_lines
from thermal_comp.host.cli import main
from thermal_comp.host.io import load_run, write_run
from thermal_comp.host.train import describe, outside_training

ROOT = Path(__file__).resolve().parents[3]
FL = ROOT / "examples" / "fl_thermal_steps.csv"


def _write(path: Path, n: int, heat: float, seed: int) -> None:
    """Two sensors that follow a heating curve scaled by ``heat`` (and one that does not),
    a spindle speed column, and a displacement driven by the first two."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 60.0
    rise = heat * (1 - np.exp(-t / 3600.0))
    cols = {"T1": 20 + 4 * rise + 0.02 * rng.normal(size=n),
            "T2": 21 + 2 * rise + 0.02 * rng.normal(size=n),
            "T3": 22 + 0.02 * rng.normal(size=n),
            "spindle_rpm": np.full(n, 1000.0 * heat),
            "dz_um": 3 * (4 * rise) - 2 * (2 * rise) + 0.05 * rng.normal(size=n)}
    write_run(path, t, cols)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    d = tmp_path_factory.mktemp("extrapolation")
    paths = {"train": d / "train.csv", "hot": d / "hot.csv", "mild": d / "mild.csv"}
    _write(paths["train"], 400, 1.0, 1)
    _write(paths["hot"], 300, 1.5, 2)  # 50 % more heat than training
    _write(paths["mild"], 300, 0.6, 3)  # stays inside
    assert main(["train",
                 "--fit", "ols", "--no-nested",
                 str(paths["train"]), "--target", "dz_um", "--groups", "3",
                 "--out", str(d / "m"), "--no-codegen", "--no-effects", "--json"]) == 0
    return paths, d / "m" / "model.json"


def _columns(path: Path) -> dict[str, np.ndarray]:
    header = path.read_text().splitlines()[0].split(",")
    data = np.loadtxt(path, delimiter=",", skiprows=1)
    return {name: data[:, i] for i, name in enumerate(header)}


def test_model_stores_each_wired_input_training_range(trained):
    paths, model_path = trained
    model = read_model(model_path)
    cols = _columns(paths["train"])
    for c in model["channels"]:
        assert c["trained_min_c"] == pytest.approx(cols[c["sensor"]].min(), abs=1e-9)
        assert c["trained_max_c"] == pytest.approx(cols[c["sensor"]].max(), abs=1e-9)
    assert model["aux"] == []  # aux inputs are declared (with their range) only when used


def test_a_hotter_run_is_flagged_with_distance_share_and_time_outside(trained):
    paths, model_path = trained
    model = read_model(model_path)
    run = load_run(paths["hot"], ["dz_um"], "T*")
    rows = evaluate_model(model, run)["outside_training_range"]
    train, hot = _columns(paths["train"]), _columns(paths["hot"])
    heated = [c["sensor"] for c in model["channels"] if c["sensor"] in ("T1", "T2")]
    assert heated, "the fit must use a heated sensor for this test to mean anything"
    assert [r["input"] for r in rows] == heated
    for r in rows:
        lo, hi = train[r["input"]].min(), train[r["input"]].max()
        x = hot[r["input"]]
        assert r["beyond"] == pytest.approx(x.max() - hi, abs=1e-9)
        assert r["beyond_share"] == pytest.approx((x.max() - hi) / (hi - lo), rel=1e-9)
        tol = 0.05 * (hi - lo)  # noise-level excursions are not extrapolation
        assert r["samples_outside_pct"] == pytest.approx(
            100 * np.mean((x < lo - tol) | (x > hi + tol)))
        assert r["beyond"] > 0.5  # 50 % more heat: degrees, not noise
    line = describe(rows, {r["input"]: " °C" for r in rows})[0]
    assert line.startswith(f"outside training: {rows[0]['input']} up to ") and "above" in line


def test_a_run_inside_the_training_range_is_not_flagged(trained):
    paths, model_path = trained
    run = load_run(paths["mild"], ["dz_um"], "T*")
    # its first samples dip below the training minimum by sensor noise (0.02 C) only
    train, mild = _columns(paths["train"]), _columns(paths["mild"])
    assert any(mild[s].min() < train[s].min() for s in ("T1", "T2", "T3"))
    assert outside_training(read_model(model_path), run) == []


def test_cli_evaluate_and_diagnose_say_it(trained, capsys):
    paths, model_path = trained
    assert main(["evaluate", str(model_path), str(paths["hot"])]) == 0
    out = capsys.readouterr().out
    assert "outside training: " in out and "expect larger errors" in out
    assert main(["evaluate", str(model_path), str(paths["hot"]), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["outside_training_range"]
    model = read_model(model_path)
    doc = diagnose(model, load_run(paths["hot"], ["dz_um"], "T*"))
    assert doc["outside_training_range"] == outside_training(
        model, load_run(paths["hot"], ["dz_um"], "T*"))
    assert any(line.startswith("outside training:") for line in summary_lines(doc))


def test_older_models_without_ranges_say_so(trained):
    paths, model_path = trained
    model = read_model(model_path)
    for c in model["channels"]:
        del c["trained_min_c"], c["trained_max_c"]
    run = load_run(paths["hot"], ["dz_um"], "T*")
    assert outside_training(model, run) is None
    assert "not stored" in describe(None)[0]


def test_the_hotter_fl_cycle_leaves_the_training_range(tmp_path, capsys):
    """Real data: the 5000 rpm cycle (24-32 h) heats the machine beyond the first three."""
    assert main(["split", str(FL), "--at-hours", "24", "-o", str(tmp_path), "--json"]) == 0
    first, second = (Path(p) for p in json.loads(capsys.readouterr().out)["parts"])
    assert main(["train", "--fit", "ols", "--no-nested",
                 str(first), "--target", "ch3_um", "--out", str(tmp_path / "m"),
                 "--no-codegen", "--no-effects", "--json"]) == 0
    capsys.readouterr()
    model = read_model(tmp_path / "m" / "model.json")
    rows = evaluate_model(model, load_run(second, ["ch3_um"], "T*"))["outside_training_range"]
    a, b = _columns(first), _columns(second)
    tol = {s: 0.05 * (a[s].max() - a[s].min()) for s in a}
    wired = [c["sensor"] for c in sorted(model["channels"], key=lambda c: c["channel"])]
    expected = [s for s in wired
                if b[s].max() > a[s].max() + tol[s] or b[s].min() < a[s].min() - tol[s]]
    assert expected and [r["input"] for r in rows] == expected


@pytest.mark.parametrize("edit, message", [
    ({"trained_min_c": 30.0, "trained_max_c": 20.0}, "training range 30..20 is empty"),
    ({"trained_min_c": "warm", "trained_max_c": 20.0}, "must both be finite numbers"),
    ({"trained_min_c": 20.0}, "must both be finite numbers"),  # half a range
])
def test_a_broken_training_range_is_refused_with_the_channel_named(trained, tmp_path, edit,
                                                                     message):
    _, model_path = trained
    model = json.loads(model_path.read_text())
    model["channels"][0] = {k: v for k, v in model["channels"][0].items()
                            if not k.startswith("trained_")} | edit
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(model))
    with pytest.raises(ModelFormatError, match=message) as err:
        read_model(bad)
    assert str(bad) in str(err.value) and model["channels"][0]["sensor"] in str(err.value)

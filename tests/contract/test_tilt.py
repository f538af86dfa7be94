"""Tilt axes (paper 002's two-height gap probes): ``--tilt NAME=UPPER,LOWER,DISTANCE_MM`` gives
an axis in µrad that trains, evaluates, generates and runs on the box like any other."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from thermal_comp import codegen
from thermal_comp.cnc.thermalcomp import ConfigError, load_config
from thermal_comp.contract.errors import InputError
from thermal_comp.contract.model_file import ModelFormatError, check_model
from thermal_comp.contract.tilt import Tilt, available_axes, unit_of
from thermal_comp.host.io import load_run, write_run
from thermal_comp.host.sim import SimConfig, build_program, simulate, write_simulation

REPO = Path(__file__).resolve().parents[2]
DISTANCE_MM = 150.0
TILT = f"tilt_y_urad=dy_top_um,dy_bottom_um,{DISTANCE_MM:g}"


def _five_probe_run(tmp: Path, protocol: str, seed: int) -> Path:
    """A simulated day with two probes on the test bar's Y side: the upper reads the tool's dy,
    the lower, nearer the spindle nose, part of dy and of dz (the column bends)."""
    program = build_program(protocol, hours=4.0, cool_hours=2.0, seed=seed)
    write_simulation(simulate(program, SimConfig(seed=seed, machine_seed=0)),
                     tmp / f"{protocol}_sim.csv")
    run = load_run(tmp / f"{protocol}_sim.csv", ["dy_um", "dz_um"], "T*", ["spindle_rpm"])
    cols = {n: run.temperatures[:, i] for i, n in enumerate(run.sensor_names)}
    cols["spindle_rpm"] = run.aux[:, 0]
    dy, dz = run.target("dy_um"), run.target("dz_um")
    cols["dz_um"] = dz
    cols["dy_top_um"] = dy
    cols["dy_bottom_um"] = 0.4 * dy + 0.3 * dz
    path = tmp / f"{protocol}.csv"
    write_run(path, run.time_s, cols, precision=10)
    return path


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("tilt")
    return tmp, _five_probe_run(tmp, "step", 1), _five_probe_run(tmp, "random", 2)


def test_a_tilt_spec_is_parsed_or_refused_with_the_reason():
    t = Tilt.parse(TILT)
    assert (t.name, t.upper, t.lower, t.distance_mm) == ("tilt_y_urad", "dy_top_um",
                                                          "dy_bottom_um", 150.0)
    assert t.of(13.0, 1.0) == pytest.approx(80.0)  # 12 um over 150 mm = 80 urad
    assert unit_of("tilt_y_urad") == "urad" and unit_of("dz_um") == "um"
    for text, reason in (("tilt_y_urad=a,b", "NAME=UPPER,LOWER,DISTANCE_MM"),
                         ("tilt_y=a,b,100", "ends in '_urad'"),
                         ("tilt_y_urad=a,a,100", "the same column"),
                         ("tilt_y_urad=a,b,0", "positive number of mm"),
                         ("tilt_y_urad=a,b,-5", "positive number of mm"),
                         ("tilt_y_urad=a,b,wide", "not a number")):
        with pytest.raises(InputError, match=reason):
            Tilt.parse(text)
    assert available_axes(["time_s", "dy_top_um", "dz_um"], ["tilt_y_urad", "dz_um"],
                          [t]) == ["dz_um"]  # a tilt needs both probes


def test_the_tilt_is_computed_from_the_two_probes_and_a_missing_probe_is_named(runs):
    tmp, step, _ = runs
    t = Tilt.parse(TILT)
    run = load_run(step, ["tilt_y_urad", "dz_um"], "T*", ["spindle_rpm"], tilts=[t])
    raw = np.genfromtxt(step, delimiter=",", names=True)
    want = (raw["dy_top_um"] - raw["dy_bottom_um"]) * 1000.0 / DISTANCE_MM
    np.testing.assert_allclose(run.target("tilt_y_urad"), want, rtol=1e-12, atol=1e-9)
    assert "dy_top_um" not in run.sensor_names and run.target_names == ["tilt_y_urad", "dz_um"]
    text = step.read_text().replace("dy_bottom_um", "dy_low_um")
    (tmp / "renamed.csv").write_text(text)
    with pytest.raises(InputError, match=r"line 1.*dy_bottom_um.*gap probe of --tilt "
                                         r"tilt_y_urad"):
        load_run(tmp / "renamed.csv", ["tilt_y_urad"], "T*", tilts=[t])


def _host(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "thermal_comp.host", *args], capture_output=True,
                           text=True,
                          cwd=cwd)


@pytest.fixture(scope="module")
def trained(runs) -> Path:
    """``host train`` with a tilt on the first simulated day: the model.json path."""
    tmp, step, _ = runs
    done = _host("train", str(step), "--target", "dz_um", "--tilt", TILT, "--aux",
                 "spindle_rpm", "--out", str(tmp / "m"), "--no-nested", "-q", cwd=REPO)
    assert done.returncode == 0, done.stderr
    return tmp / "m" / "model.json"


def test_a_tilt_axis_trains_evaluates_and_generates_like_any_axis(runs, trained):
    tmp, step, random = runs
    model = json.loads(trained.read_text())
    assert model["axes"]["tilt_y_urad"]["unit"] == "urad" and model["axes"]["dz_um"]["unit"] == "um"
    assert model["tilts"] == [Tilt.parse(TILT).to_json()]
    check_model(model)
    # judged on a day it never saw, from that day's own probes
    ev = _host("evaluate", str(tmp / "m" / "model.json"), str(random), "--json", cwd=REPO)
    assert ev.returncode == 0, ev.stderr
    axis = json.loads(ev.stdout)["axes"]["tilt_y_urad"]
    assert axis["rmse_um"] < 0.5 * axis["raw_rms_um"], axis
    header = (tmp / "m" / "model.h").read_text()
    assert "intercept:" in header and "nanoradians" in header and "in urad" in header
    # the validator keeps the name and the unit together, and the tilts on µrad axes
    bad = json.loads(json.dumps(model))
    bad["axes"]["tilt_y_urad"]["unit"] = "um"
    with pytest.raises(ModelFormatError, match="the name declares 'urad'"):
        check_model(bad)
    bad = json.loads(json.dumps(model))
    bad["tilts"][0]["name"] = "dz_um"
    with pytest.raises(ModelFormatError, match=r"tilts\[0\]"):
        check_model(bad)
    units = {ax.name: ax.unit for ax in codegen.generate(model).model.axes}
    assert units == {"dz_um": "um", "tilt_y_urad": "urad"}


@pytest.mark.skipif(shutil.which("gcc") is None or shutil.which("make") is None,
                    reason="gcc/make not installed: the native firmware cannot be built")
def test_the_box_runs_a_tilt_axis_bit_exact_with_the_twin(runs, trained):
    from thermal_comp.hil import replay as hil_replay

    tmp, _, random = runs
    setup = hil_replay.prepare(trained, random, tmp / "hil")
    assert "tilt_y_urad" in setup.feed.measured
    report, _ = hil_replay.run(setup)
    assert report.checks["twin_bit_exact"] and report.checks["float_within_bound"], \
        report.problems
    tilt = report.axes["tilt_y_urad"]
    assert tilt.compensated_rms_um < 0.5 * tilt.raw_rms_um


def test_linuxcnc_refuses_to_drive_a_linear_axis_from_a_tilt(tmp_path):
    conf = (REPO / "thermal_comp" / "cnc" / "config" / "thermalcomp.conf").read_text()
    section = conf[conf.index("[axis."):]
    box_axis = next(line for line in section.splitlines() if line.startswith("box_axis"))
    (tmp_path / "t.conf").write_text(conf.replace(box_axis, "box_axis = tilt_y_urad", 1))
    with pytest.raises(ConfigError, match="tilt axis"):
        load_config(tmp_path / "t.conf")


def test_figures_and_the_equation_speak_in_the_tilt_unit():
    from thermal_comp.contract.terms import make_temp
    from thermal_comp.host.analysis import plots
    from thermal_comp.host.analysis.metrology import term_unit

    t = np.arange(50) * 60.0
    fig = plots.run_fit("day", "tilt_y_urad", t, np.sin(t / 600.0), {"m": np.sin(t / 600.0)},
                        (1.0, [0.5, 1.5]))
    assert fig.axes[0].get_ylabel() == "tilt (µrad)"
    assert all("µm" not in lb for lb in fig.axes[1].get_legend_handles_labels()[1])
    assert plots.run_fit("day", "dz_um", t, t, {"m": t}).axes[0].get_ylabel() \
        == "displacement (µm)"
    assert term_unit(make_temp("T01"), out="µrad") == "µrad/K"


def test_the_report_states_an_effects_evidence_in_the_axis_unit():
    from thermal_comp.host.analysis.report_story import effect_stages
    from thermal_comp.host.io import Run

    t = np.arange(40) * 60.0
    temp = 20 + t / 600.0
    run = Run("day.csv", t, ["T01"], temp[:, None], ["tilt_y_urad", "dz_um"],
              np.column_stack([temp, temp]))
    term = {"kind": "temp", "source": "T01", "coef": 1.0}
    effect = {"kind": "lag", "name": "lag(T01, tau=600s)", "rmse_before_um": 2.0,
              "rmse_after_um": 1.0, "intercept": 0.0, "terms": [term]}
    axis = {"baseline": {"intercept": 0.0, "terms": [term]}, "effects": [effect],
            "terms": [term], "intercept": 0.0}
    tilt = effect_stages(axis, "tilt_y_urad", run, 60.0)[1]["evidence"]
    assert "2.00 → 1.00 µrad" in tilt and "µm" not in tilt
    assert "2.00 → 1.00 µm" in effect_stages(axis, "dz_um", run, 60.0)[1]["evidence"]

"""HIL: the native firmware replays the example runs over a pty and matches the host exactly.

The firmware is the real application built for BOARD=native; the expectation is the integer
twin (codegen.fixed) plus the documented output stage, and the raw/compensated residuals are
recomputed here from the CSV with numpy. Every comparison the runner makes is also shown to
fail when the firmware's lines are altered (lost, duplicated, reordered, off by one nm).
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import shutil
import subprocess
import sys
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest

from thermal_comp.contract.model_file import dumps
from thermal_comp.contract.protocol import decode, encode_sample
from thermal_comp.hil import replay as hil_replay
from thermal_comp.hil.build import build_firmware
from thermal_comp.hil.checks import judge
from thermal_comp.hil.example_model import (
    default_terms,
    fit_example_model,
    fl_thermal_model,
    write_model,
)
from thermal_comp.hil.runner import Capture
from thermal_comp.host.io import split_file
from thermal_comp.host.train import train_model

REPO = Path(__file__).resolve().parents[2]
FL = REPO / "examples" / "fl_thermal_steps.csv"
SIM_RUNS = sorted((REPO / "examples").glob("sim_*.csv"))

pytestmark = pytest.mark.skipif(
    shutil.which("gcc") is None or shutil.which("make") is None,
    reason="gcc/make not installed: the native firmware cannot be built")


def fl_model() -> dict:
    return fl_thermal_model(FL)


@pytest.fixture(scope="module")
def fl_setup(tmp_path_factory):
    d = tmp_path_factory.mktemp("hil_fl")
    model = write_model(fl_model(), d / "model.json")
    return hil_replay.prepare(model, FL, d / "hil")


@pytest.fixture(scope="module")
def fl_result(fl_setup):
    return hil_replay.run(fl_setup)


def csv_columns(path: Path) -> dict[str, np.ndarray]:
    with path.open() as fh:
        rows = list(csv.reader(fh))
    data = np.array(rows[1:], dtype=float)
    return {name: data[:, i] for i, name in enumerate(rows[0])}


def test_fl_thermal_replay_matches_twin_bit_for_bit(fl_setup, fl_result):
    report, capture = fl_result
    cols = csv_columns(FL)
    n = len(cols["time_s"])
    assert report.samples == n and report.received == n
    assert report.checks == {"twin_bit_exact": True, "float_within_bound": True,
                             "no_lost_duplicated_reordered": True, "held_within_limit": True,
                             "limited_within_limit": True, "clamped_within_limit": True,
                             "corrected": True, "no_worse_than_uncompensated": True,
                             "steps_within_limit": True}, report.problems
    assert report.mismatches == 0 and report.max_abs_diff_nm == 0
    assert report.ok
    assert capture.sessions[0].exit_code == 0  # the firmware exited cleanly on Q
    # The box echoes the codes it sampled: the CSV temperatures rounded to 1/128 degC.
    lines = [decode(raw) for raw in capture.sessions[0].lines if raw.startswith(b"$C,")]
    t10 = np.array([s.temp_codes[0] for s in lines])
    want = np.sign(cols["T10"]) * np.floor(np.abs(cols["T10"]) * 128 + 0.5)
    np.testing.assert_array_equal(t10, want)


def test_float_model_compared_on_most_samples_within_the_codegen_bound(fl_setup, fl_result):
    report, _ = fl_result
    for name, axis in report.axes.items():
        assert axis.bound_um is not None and 0 < axis.bound_um <= 0.01
        # compared wherever the box outputs the model value (not during the cold-start walk)
        assert axis.float_samples > 0.95 * report.samples, name
        assert axis.float_max_diff_um <= axis.bound_um


def test_residuals_are_measured_minus_correction(fl_result):
    report, capture = fl_result
    cols = csv_columns(FL)
    lines = [decode(raw) for raw in capture.sessions[0].lines if raw.startswith(b"$C,")]
    for a, name in enumerate(["ch1_um", "ch3_um"]):
        corr_um = np.array([s.corrections_nm[a] for s in lines]) / 1000.0
        meas = cols[name]
        ax = report.axes[name]
        assert ax.raw_rms_um == pytest.approx(np.sqrt(np.mean(meas ** 2)), rel=1e-12)
        assert ax.raw_peak_um == pytest.approx(np.abs(meas).max(), rel=1e-12)
        assert ax.compensated_rms_um == pytest.approx(np.sqrt(np.mean((meas - corr_um) ** 2)),
                                                      rel=1e-12)
        assert ax.compensated_peak_um == pytest.approx(np.abs(meas - corr_um).max(), rel=1e-12)
        # the model is worth having on this run
        assert ax.compensated_rms_um < 0.5 * ax.raw_rms_um


def _altered(capture: Capture, edit) -> Capture:
    s = capture.sessions[0]
    lines = list(s.lines)
    edit(lines)
    return dataclasses.replace(capture, sessions=[dataclasses.replace(s, lines=lines)])


def _sample_positions(lines: list[bytes]) -> list[int]:
    return [i for i, raw in enumerate(lines) if raw.startswith(b"$C,")]


def _rejudge(setup, capture):
    return judge(capture, hil_replay.expectations(setup, capture, ()), setup.feed,
                 setup.model, setup.bounds_um())


def test_checks_catch_lost_duplicated_reordered_and_wrong_lines(fl_setup, fl_result):
    _, capture = fl_result

    def drop(lines):
        del lines[_sample_positions(lines)[100]]

    def dup(lines):
        i = _sample_positions(lines)[200]
        lines.insert(i, lines[i])

    def swap(lines):
        i, j = _sample_positions(lines)[300:302]
        lines[i], lines[j] = lines[j], lines[i]

    def off_by_one_nm(lines):
        i = _sample_positions(lines)[400]
        s = decode(lines[i])
        lines[i] = encode_sample(s.seq, s.status, [s.corrections_nm[0] + 1,
                                                   *s.corrections_nm[1:]],
                                 s.temp_codes).rstrip(b"\r\n")

    def corrupt(lines):
        i = _sample_positions(lines)[500]
        lines[i] = lines[i].replace(b",", b";", 1)

    lost = _rejudge(fl_setup, _altered(capture, drop))
    assert (lost.lost, lost.duplicated, lost.reordered, lost.ok) == (1, 0, 0, False)
    twice = _rejudge(fl_setup, _altered(capture, dup))
    assert (twice.lost, twice.duplicated, twice.ok) == (0, 1, False)
    swapped = _rejudge(fl_setup, _altered(capture, swap))
    assert (swapped.reordered, swapped.lost, swapped.ok) == (1, 0, False)
    wrong = _rejudge(fl_setup, _altered(capture, off_by_one_nm))
    assert (wrong.mismatches, wrong.max_abs_diff_nm, wrong.ok) == (1, 1, False)
    assert wrong.axes["ch1_um"].mismatches == 1 and wrong.axes["ch3_um"].mismatches == 0
    bad = _rejudge(fl_setup, _altered(capture, corrupt))
    assert (bad.bad_lines, bad.lost, bad.ok) == (1, 1, False)
    assert _rejudge(fl_setup, capture).ok  # the unaltered capture still passes


@pytest.mark.skipif(not SIM_RUNS, reason="no examples/sim_*.csv yet (made by host simulate)")
@pytest.mark.parametrize("run", SIM_RUNS, ids=lambda p: p.stem)
def test_simulated_example_runs_replay_bit_exact(run, tmp_path):
    cols = csv_columns(run)
    targets = [c for c in cols if c.endswith("_um")]
    sensors = [c for c in cols if c.startswith("T")]
    aux = "spindle_rpm" if "spindle_rpm" in cols else None
    period = float(np.median(np.diff(cols["time_s"])))
    terms = default_terms(sensors[:3], period, aux)
    model = write_model(fit_example_model(run, {t: terms for t in targets},
                                          aux_names=[aux] if aux else []),
                        tmp_path / "model.json")
    report, capture = hil_replay.run(hil_replay.prepare(model, run, tmp_path / "hil"))
    assert report.ok, report.problems
    assert report.received == len(cols["time_s"])
    assert capture.sessions[0].exit_code == 0


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "thermal_comp.hil", "replay", *args],
                           capture_output=True,
                          text=True, cwd=REPO, timeout=120)


def test_cli_json_shape_and_exit_codes(fl_setup, tmp_path):
    model = tmp_path / "model.json"
    model.write_text(json.dumps(fl_setup.model))
    build = str(fl_setup.binary.parent.parent)
    ok = _cli("--model", str(model), "--data", str(FL), "--json", "--build-dir", build)
    assert ok.returncode == 0, ok.stderr
    out = json.loads(ok.stdout)
    assert out["samples"] == fl_setup.feed.n_samples and out["mismatches"] == 0
    assert out["max_abs_diff_nm"] == 0
    assert set(out["axes"]) == {"ch1_um", "ch3_um"}
    for axis in out["axes"].values():
        assert {"raw_rms_um", "compensated_rms_um", "raw_peak_um", "compensated_peak_um",
                "float_max_diff_um", "bound_um"} <= set(axis)
    assert ok.stderr == ""  # quiet with --json: no progress bar

    # the table names every check and the result
    table = _cli("--model", str(model), "--data", str(FL), "--build-dir", build)
    assert table.returncode == 0 and "RESULT: PASS" in table.stdout
    assert "ch3_um" in table.stdout and "bit for bit" in table.stdout

    # a run without a column the model needs is bad input: exit 2 naming the column
    short = tmp_path / "no_t10.csv"
    cols = csv_columns(FL)
    names = [c for c in cols if c != "T10"]
    np.savetxt(short, np.column_stack([cols[c][:50] for c in names]), delimiter=",",
               header=",".join(names), comments="")
    bad = _cli("--model", str(model), "--data", str(short), "--json", "--build-dir", build)
    assert bad.returncode == 2 and "T10" in bad.stderr


def test_cli_exit_code_1_when_the_firmware_disagrees(fl_setup, tmp_path):
    # A firmware built with a different slew limit than the host expects: same model, so the
    # twin still agrees, but the cold-start walk differs -> correction and status mismatches.
    other = build_firmware(fl_setup.build.header_path, tmp_path, "native",
                           "-DBOX_SLEW_NM_PER_S=7")
    model = tmp_path / "model.json"
    model.write_text(json.dumps(fl_setup.model))
    res = _cli("--model", str(model), "--data", str(FL), "--json", "--firmware", str(other),
               "--build-dir", str(tmp_path))
    assert res.returncode == 1, res.stderr
    out = json.loads(res.stdout)
    assert out["mismatches"] > 0 and out["ok"] is False


def test_a_model_larger_than_the_firmware_capacity_is_refused_up_front(tmp_path):
    from thermal_comp.contract.terms import make_temp
    from thermal_comp.hil.example_model import fit_example_model as fit
    from thermal_comp.hil.expect import OutputConfig

    sensors = [f"T{i:02d}" for i in range(1, 10)]  # 9 channels; box_config.h allows 8
    model = tmp_path / "model.json"  # written by hand: write_model refuses it (issue 14)
    model.write_text(dumps(fit(FL, {"ch1_um": [make_temp(s) for s in sensors]})))
    with pytest.raises(ValueError, match="9 channels.*BOX_MAX_CHANNELS"):
        hil_replay.prepare(model, FL, tmp_path / "hil")
    # a firmware built for more channels accepts it
    OutputConfig.from_build("-DBOX_MAX_CHANNELS=16").check_fits(9, 1, 0, "model")


def test_a_box_that_stops_answering_fails_the_replay_and_says_where(fl_setup):
    from thermal_comp.hil.runner import CodeOverride

    # A code outside the chip's 19-bit range is a feed error: the native board exits (code 2)
    # at sample 500, as a crashed box would stop talking.
    report, capture = hil_replay.run(fl_setup, [CodeOverride(500, 501, 0, 1 << 20)])
    assert not report.ok and report.problems_fatal
    # (lines still in the pty when the process died may be gone with it: Linux discards a
    # pty's buffer when the slave side closes, so under load even all 500 can be lost)
    assert report.received <= 500 and report.lost == report.samples - report.received
    assert capture.sessions[0].exit_code == 2
    # whatever the pty lost, the box's own last words say which sample killed it
    assert any("(sample 500): S: code '1048576'" in p for p in report.problems), report.problems


def test_box_flags_extrapolation_on_the_hotter_fl_cycle(tmp_path):
    """Trained on 0-24 h, the box replays the 5000 rpm cycle (24-32 h): every sample whose
    reading of a wired channel leaves the training window carries EXTRAP, and only those; the
    window is recomputed here from docs/protocol.md's rule, exactly, from the CSV files."""
    first, second = split_file(FL, [24 * 3600.0], tmp_path)
    model = train_model([first], ["ch3_um"], effects=False, fit="ols", nested=False)
    model_path = write_model(model, tmp_path / "model.json")
    report, _ = hil_replay.run(hil_replay.prepare(model_path, second, tmp_path / "hil"))
    assert report.ok and report.status_mismatches == 0, report.problems

    train, test = csv_columns(first), csv_columns(second)
    beyond = np.zeros(len(test["time_s"]), dtype=bool)
    for c in model["channels"]:
        lo, hi = Fraction(train[c["sensor"]].min()), Fraction(train[c["sensor"]].max())
        w_lo = math.floor((lo - (hi - lo) / 20) * 128)
        w_hi = math.ceil((hi + (hi - lo) / 20) * 128)
        code = np.sign(test[c["sensor"]]) * np.floor(np.abs(test[c["sensor"]]) * 128 + 0.5)
        beyond |= (code < w_lo) | (code > w_hi)
    assert beyond.sum() > 0.2 * beyond.size  # the hotter cycle is far outside, not by noise
    assert report.status_counts.get("EXTRAP", 0) == int(beyond.sum())
    got = (report.fw_status >> 10) & 1
    np.testing.assert_array_equal(got.astype(bool), beyond)

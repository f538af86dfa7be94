"""`host report` on the real FL_THERMAL data: every figure is a real, non-blank PNG, the numbers
in the summary agree with an independent computation, and headless Chromium loads the page."""

from __future__ import annotations

import html
import json
import re
import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import matplotlib.image as mpimg
import numpy as np
import pytest
from direct_fits import direct_lag

from thermal_comp.host.analysis.report import build_report
from thermal_comp.host.analysis.report_data import ReportError, load_protocols
from thermal_comp.host.cli import main as host_main
from thermal_comp.host.io import load_run, write_run

ROOT = Path(__file__).resolve().parents[3]
FL = ROOT / "examples" / "fl_thermal_steps.csv"
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
AXES = ("ch3_um", "ch5_um")
TAU_S = 1800.0
PERIOD_S = 60.0


lag = direct_lag  # written out as a loop, independent of host.fitting


def best_delay(y: np.ndarray, x: np.ndarray, max_lag: int) -> float:
    """Lag (s) of the strongest correlation, positive when the temperature lags."""
    lags = np.arange(-max_lag, max_lag + 1)
    r = [abs(np.corrcoef(y[: len(y) - k], x[k:])[0, 1]) if k >= 0
         else abs(np.corrcoef(y[-k:], x[: len(x) + k])[0, 1]) for k in lags]
    return float(lags[int(np.argmax(r))] * PERIOD_S)


@pytest.fixture(scope="module")
def example(tmp_path_factory):
    """Two 16 h halves of the real run at 60 s, and a model fitted on the first with numpy."""
    tmp = tmp_path_factory.mktemp("report_inputs")
    full = load_run(FL, list(AXES), "T*", ["spindle_rpm"])
    keep = np.arange(0, full.n_samples, 4)  # 15 s -> 60 s
    half = len(keep) // 2
    paths = []
    for name, rows in (("fl_first", keep[:half]), ("fl_second", keep[half:])):
        cols = {n: full.temperatures[rows, i] for i, n in enumerate(full.sensor_names)}
        cols["spindle_rpm"] = full.aux[rows, 0]
        cols.update({n: full.displacements[rows, i] for i, n in enumerate(AXES)})
        path = tmp / f"{name}.csv"
        write_run(path, full.time_s[rows] - full.time_s[rows[0]], cols)
        paths.append(path)

    train = load_run(paths[0], list(AXES), "T*", ["spindle_rpm"])
    alpha = round((1 - np.exp(-PERIOD_S / TAU_S)) * 2**30) / 2**30
    sensors_used = {"ch3_um": ("T01", "T05"), "ch5_um": ("T11", "T16")}
    axes = {}
    for axis, (s_temp, s_lag) in sensors_used.items():
        y = train.target(axis)
        X = np.column_stack([train.column(s_temp), lag(train.column(s_lag), alpha)])
        A = np.column_stack([np.ones(len(y)), X])
        coef, *_ = np.linalg.lstsq(A, y, rcond=None)
        corr = {s: float(np.corrcoef(y, train.column(s))[0, 1]) for s in train.sensor_names}
        delays = {s: best_delay(y, train.column(s), 120) for s in train.sensor_names}
        labels = {s: int(corr[s] > 0) * 3 + int(np.digitize(delays[s], [-1800, 1800]))
                  for s in train.sensor_names}
        raw = float(np.sqrt(np.mean(y ** 2)))
        # the temperature-only baseline the effect (lag of the second sensor) was added to
        base, *_ = np.linalg.lstsq(A[:, :2], y, rcond=None)
        axes[axis] = {
            "unit": "um", "intercept": float(coef[0]),
            "terms": [{"kind": "temp", "source": s_temp, "coef": float(coef[1])},
                      {"kind": "lag", "source": s_lag, "tau_s": TAU_S, "alpha": alpha,
                       "coef": float(coef[2])}],
            "selection": {"method": "hand-made for the test", "sensors": [s_temp, s_lag],
                          "correlations": corr, "delays_s": delays, "labels": labels,
                          "ec_curve": [1.0, 0.55, 0.62, 0.71, 0.9],
                          "ec_subsets": [[s_temp], [s_temp, s_lag]], "chosen_count": 2},
            "metrics": {"validation_rmse_um": raw / 4, "raw_rms_um": raw,
                        "validation": "time-blocked"},
            "baseline_validation_rmse_um": raw / 3,
            "baseline": {"intercept": float(base[0]),
                         "terms": [{"kind": "temp", "source": s_temp, "coef": float(base[1])}]},
            "effects": [{"kind": "lag", "name": f"lag({s_lag}, tau=1800s)",
                         "rmse_before_um": 3.21, "rmse_after_um": 1.23,
                         "evidence": {"improvement_pct": 61.7, "folds_improved": "3/3",
                                      "residual_corr": -0.48},
                         "intercept": float(coef[0]), "terms": "FINAL"}],
        }
        axes[axis]["effects"][0]["terms"] = axes[axis]["terms"]
        if axis == "ch5_um":  # the validated count rule, with a group-refinement swap
            axes[axis]["selection"].update({
                "count_rule": "smallest out-of-fold error S_i",
                "ec_errors_um": [5.0, 2.2, 2.4, 2.6, 3.0],
                "refinement": [{"removed": "T16", "added": s_temp, "error_before_um": 2.5,
                                "error_after_um": 2.2}]})
    channels = sorted({s for pair in sensors_used.values() for s in pair})
    model = {
        "schema": "thermal-model/1", "tool_version": "0.1.0", "sample_period_s": PERIOD_S,
        "channels": [{"channel": i, "sensor": s, "tc_type": "K", "min_c": -40.0, "max_c": 200.0,
                      "trained_min_c": float(train.column(s).min()),
                      "trained_max_c": float(train.column(s).max())}
                     for i, s in enumerate(channels)],
        "aux": [], "time_max_s": 604800.0, "axes": axes,
        "training": {"runs": [str(paths[0])], "targets": list(AXES), "sensors": "T*"},
        "fixed_point": {"axes": {"ch3_um": {"bound_um": 0.0042}}},
    }
    model_path = tmp / "model.json"
    model_path.write_text(json.dumps(model))
    protocols = tmp / "protocols.json"
    protocols.write_text(json.dumps({
        "metric": "validation RMSE (µm)", "train": ["constant", "step", "random"],
        "test": ["constant", "step", "random"],
        "matrix": [[1.1, 2.5, 2.9], [1.9, 1.2, 1.6], [2.2, 1.7, 1.3]]}))
    hil = tmp / "hil_fl_second.json"
    hil.write_text(json.dumps({
        "samples": 960, "mismatches": 0, "lost": 0, "bad_lines": 0,
        "status_counts": {"SLEW": 1, "EXTRAP": 412},
        "checks": {"twin_bit_exact": True, "float_within_bound": True},
        "axes": {"ch3_um": {"raw_rms_um": 37.3, "compensated_rms_um": 29.55, "mismatches": 0,
                            "float_max_diff_um": 0.00041, "bound_um": 0.0042}}}))
    return {"model": model, "model_path": model_path, "runs": paths, "protocols": protocols,
            "hil": hil,
            "alpha": alpha, "sensors_used": sensors_used}


@pytest.fixture(scope="module")
def rendered(example, tmp_path_factory):
    out = tmp_path_factory.mktemp("report_out")
    report = build_report(example["model_path"], example["runs"], out,
                          protocols=example["protocols"], quiet=True, hil=[example["hil"]])
    return report


def expected_files() -> set[str]:
    files = {"protocols.png", "window_fl_first.png", "window_fl_second.png"}
    for axis in AXES:
        files |= {f"selection_{axis}.png", f"ec_{axis}.png"}
        for run in ("fl_first", "fl_second"):
            files |= {f"run_{run}_{axis}.png", f"hysteresis_{run}_{axis}.png",
                      f"effects_{run}_{axis}.png"}
    return files


def test_every_figure_is_a_valid_non_blank_png(rendered):
    out = rendered.out_dir
    assert {p.name for p in out.glob("*.png")} == expected_files()
    for name in expected_files():
        data = (out / name).read_bytes()
        assert data[:8] == PNG_SIGNATURE, name
        pixels = mpimg.imread(out / name)
        assert pixels.ndim == 3 and pixels.shape[0] >= 300 and pixels.shape[1] >= 500, name
        # a blank (single-colour) canvas has zero variance; a drawn plot is far from it
        assert float(pixels[..., :3].std()) > 0.05, name


def test_html_embeds_every_figure_and_links_the_files(rendered):
    page = rendered.index.read_text()
    embedded = re.findall(r'<img src="data:image/png;base64,', page)
    assert len(embedded) == len(expected_files())
    for name in expected_files():
        assert f'href="{name}"' in page
    assert "lag(T05, tau=1800s)</b>: validation RMSE 3.21 → 1.23 µm, 62 % better" in page
    assert "HIL replay (" in page and "twin_bit_exact passed" in page
    assert "Status bits the box raised: SLEW on 1 sample, EXTRAP on 412 samples." in page
    assert "how many sensors the selection chose: the smallest EC (paper 000)." in page  # ch3
    assert "the smallest out-of-fold error S<sub>i</sub>" in page  # ch5
    assert "Group refinement then swapped T16 → " in page and "(2.5 → 2.2 µm)" in page
    assert "<td>0.410</td><td>4.200</td>" in page  # box vs float and its bound, in nm
    assert "http://" not in page and "https://" not in page  # nothing to fetch
    # the metrologist's tables: the equation, ISO 230-3 drift, the wiring sheet
    assert "δ(ch3_um) = " in page and "·lag[τ=1800 s](T05)" in page
    assert "Thermal drift (ISO 230-3)" in page
    assert '<td>0</td><td class="l">T01</td><td class="l">type K</td>' in page
    assert (rendered.out_dir / "wiring.csv").read_text().splitlines()[0].startswith(
        "box_channel,sensor,tc_type,location")


def test_runs_table_says_which_inputs_leave_the_training_range(example, rendered):
    first, second = (np.loadtxt(p, delimiter=",", skiprows=1) for p in example["runs"])
    header = example["runs"][0].read_text().splitlines()[0].split(",")
    channels = [c["sensor"] for c in example["model"]["channels"]]
    page = rendered.index.read_text()
    expected = []
    for s in channels:
        a, b = first[:, header.index(s)], second[:, header.index(s)]
        lo, hi = a.min(), a.max()
        tol = 0.05 * (hi - lo)
        if b.max() > hi + tol or b.min() < lo - tol:
            up = b.max() - hi >= lo - b.min()
            share = max(b.max() - hi, lo - b.min()) / (hi - lo)
            pct = 100 * np.mean((b < lo - tol) | (b > hi + tol))
            expected.append(f"{s} {'+' if up else '−'}{100 * share:.0f} % "
                            f"({pct:.0f} % of the run)")
    assert expected, "the second half of the FL run goes beyond the first"
    assert f'<td class="l">{", ".join(expected)}</td>' in page
    assert '<td class="l">none</td>' in page  # the training half itself


def test_summary_numbers_match_an_independent_computation(example, rendered):
    summary = json.loads((rendered.out_dir / "summary.json").read_text())
    model, alpha = example["model"], example["alpha"]
    for path in example["runs"]:
        header = path.read_text().splitlines()[0].split(",")
        table = np.loadtxt(path, delimiter=",", skiprows=1)
        col = {n: table[:, i] for i, n in enumerate(header)}
        for axis in AXES:
            s_temp, s_lag = example["sensors_used"][axis]
            terms = model["axes"][axis]["terms"]
            pred = (model["axes"][axis]["intercept"] + terms[0]["coef"] * col[s_temp]
                    + terms[1]["coef"] * lag(col[s_lag], alpha))
            row = summary["runs"][path.stem][axis]
            assert row["raw_rms_um"] == pytest.approx(np.sqrt(np.mean(col[axis] ** 2)), rel=1e-9)
            assert row["residual_rms_um"]["our model"] == pytest.approx(
                np.sqrt(np.mean((col[axis] - pred) ** 2)), rel=1e-6)
            assert row["in_training"] == (path.stem == "fl_first")
            # peer: OLS on all 16 temperatures, fitted on the training half only
            train = np.loadtxt(example["runs"][0], delimiter=",", skiprows=1)
            t_cols = [i for i, n in enumerate(header) if n.startswith("T")]
            A = np.column_stack([np.ones(len(train)), train[:, t_cols]])
            beta, *_ = np.linalg.lstsq(A, train[:, header.index(axis)], rcond=None)
            peer = np.column_stack([np.ones(len(table)), table[:, t_cols]]) @ beta
            assert row["residual_rms_um"]["OLS, all sensors"] == pytest.approx(
                np.sqrt(np.mean((col[axis] - peer) ** 2)), rel=1e-6)
            assert "4 most correlated (paper 002)" in row["residual_rms_um"]
            base = model["axes"][axis]["baseline"]
            before = col[axis] - base["intercept"] - base["terms"][0]["coef"] * col[s_temp]
            assert [s["rms_um"] for s in row["stages_rms_um"]] == pytest.approx(
                [np.sqrt(np.mean(before ** 2)), np.sqrt(np.mean((col[axis] - pred) ** 2))],
                rel=1e-6)
            assert row["baseline_rms_um"] == pytest.approx(np.sqrt(np.mean(before ** 2)),
                                                           rel=1e-6)
    # ISO 230-3 drift of the measured ch3 on each run: its range, first hour, end - start
    for path in example["runs"]:
        table = np.loadtxt(path, delimiter=",", skiprows=1)
        header = path.read_text().splitlines()[0].split(",")
        t, y = table[:, 0], table[:, header.index("ch3_um")]
        d = summary["runs"][path.stem]["ch3_um"]["drift"]["measured"]
        assert d["max_um"] == pytest.approx(y.max() - y.min())
        assert d["first_hour_um"] == pytest.approx(np.ptp(y[t <= t[0] + 3600]))
        assert d["start_to_end_um"] == pytest.approx(y[-1] - y[0])
    ch3 = next(r for r in summary["axes"] if r["axis"] == "ch3_um")
    assert ch3["sensors"] == ["T01", "T05"]
    assert ch3["coefficients"] == 3
    assert ch3["reduction_pct"] == pytest.approx(75.0)
    assert ch3["error_bound_um"] == 0.0042


CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHECK_SCRIPT = """<script>
window.addEventListener('load', function () {
  var imgs = Array.prototype.slice.call(document.images);
  var bad = imgs.filter(function (i) { return !(i.complete && i.naturalWidth > 0); });
  document.body.setAttribute('data-images', imgs.length + ':' + bad.length);
});
</script>"""


@pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed (apt-get install chromium)")
def test_page_loads_in_headless_chromium_without_errors(rendered, tmp_path):
    # A copy with a checker appended: the report itself carries no test hooks or scripts.
    probe = tmp_path / "probe.html"
    probe.write_text(rendered.index.read_text().replace("</body>", CHECK_SCRIPT + "</body>"))
    cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
           "--no-first-run", "--disable-background-networking", "--disable-component-update",
           "--disable-sync", f"--user-data-dir={tmp_path / 'profile'}", "--enable-logging=stderr",
           "--v=0", "--virtual-time-budget=5000", "--dump-dom", probe.as_uri()]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    console = [ln for ln in done.stderr.splitlines() if "CONSOLE" in ln]
    assert not console, console
    assert "Uncaught" not in done.stderr
    assert f'data-images="{len(expected_files())}:0"' in done.stdout


def test_cli_writes_the_report_and_rejects_bad_input(example, tmp_path, capsys):
    out = tmp_path / "cli_report"
    code = host_main(["report", str(example["model_path"]), "--runs", str(example["runs"][1]),
                      "-o", str(out), "--no-peers", "--json"])
    assert code == 0
    printed = json.loads(capsys.readouterr().out)
    assert Path(printed["index"]).is_file()
    assert set(printed["runs"]) == {"fl_second"}

    bad_run = tmp_path / "no_axes.csv"
    bad_run.write_text("time_s,T01,T05,T11,T16\n0,1,2,3,4\n1,1,2,3,4\n")
    code = host_main(["report", str(example["model_path"]), "--runs", str(bad_run),
                      "-o", str(tmp_path / "x"), "--no-peers"])
    err = capsys.readouterr().err
    assert code == 2 and "no_axes.csv" in err and "ch3_um" in err
    assert not (tmp_path / "x" / "index.html").exists()


def test_protocol_matrix_shape_is_checked(tmp_path):
    bad = tmp_path / "m.json"
    bad.write_text(json.dumps({"train": ["a", "b"], "test": ["a"], "matrix": [[1.0, 2.0]]}))
    with pytest.raises(ReportError, match="m.json: matrix is 1×2 but there are 2 train"):
        load_protocols(bad)
    rows = tmp_path / "rows.csv"
    rows.write_text("train,test,validation_rmse_um\na,a,1.0\na,b,2.0\nb,a,3.0\nb,b,4.0\n")
    matrix = load_protocols(rows)
    assert matrix.train == ["a", "b"] and matrix.test == ["a", "b"]
    np.testing.assert_array_equal(matrix.values, [[1.0, 2.0], [3.0, 4.0]])


@pytest.fixture(scope="module")
def budget_model(example, tmp_path_factory):
    """The example model with what the channel budget does on FL ch5: an effect found by the
    search (T05 + square(T05)) whose sensor got no box channel, and a selected sensor (T01) the
    budget took away; and ch3 whose count was capped by --max-sensors."""
    import copy

    model = copy.deepcopy(example["model"])
    ch5 = model["axes"]["ch5_um"]
    train = load_run(example["runs"][0], list(AXES), "T*")
    y = train.target("ch5_um")
    s_temp, s_lag = example["sensors_used"]["ch5_um"]
    ref = float(np.mean(train.column("T05")))
    A = np.column_stack([np.ones(len(y)), train.column(s_temp),
                         lag(train.column(s_lag), example["alpha"]), train.column("T05"),
                         (train.column("T05") - ref) ** 2])
    c, *_ = np.linalg.lstsq(A, y, rcond=None)
    dropped_terms = ch5["terms"] + [{"kind": "temp", "source": "T05", "coef": float(c[3])},
                                    {"kind": "square", "source": "T05", "ref_c": ref,
                                     "coef": float(c[4])}]
    ch5["effects"].append({"kind": "nonlinear", "name": "T05 + square(T05)",
                           "rmse_before_um": 1.23, "rmse_after_um": 1.0,
                           "evidence": {"folds_improved": "3/3"}, "dropped_for_channels": True,
                           "intercept": float(c[0]), "terms": dropped_terms})
    ch5["selection"]["sensors"] = [s_temp, s_lag, "T01"]
    ch5["channel_budget_after_effects"] = {"max_channels": 3, "dropped_sensors": ["T01", "T05"],
                                           "dropped_terms": ["T01", "T05", "square(T05)"]}
    ch3 = model["axes"]["ch3_um"]["selection"]
    ch3.update({"count_rule": "smallest out-of-fold error S_i", "chosen_count": 2,
                "ec_errors_um": [5.0, 3.0, 2.5, 2.0, 1.5]})
    model["training"]["max_sensors"] = 2
    path = tmp_path_factory.mktemp("budget") / "model.json"
    path.write_text(json.dumps(model))
    out = tmp_path_factory.mktemp("budget_out")
    return model, build_report(path, example["runs"], out, peers=False, quiet=True)


def test_report_describes_the_model_the_box_runs(example, budget_model):
    model, report = budget_model
    page = report.index.read_text()
    summary = json.loads((report.out_dir / "summary.json").read_text())
    ch5 = next(r for r in summary["axes"] if r["axis"] == "ch5_um")
    assert ch5["effects"] == ["lag(T16, tau=1800s)"]
    assert ch5["effects_dropped"] == ["T05 + square(T05)"]
    assert "T05 + square(T05) (dropped: no box channel left for its sensor)" in page
    # the selection caption names what the box reads, and T01 as dropped
    assert "the sensors the box reads for ch5_um (T11, T16)" in page
    assert "dropped by the box's channel budget (T01)" in page
    # the effects figure ends on the box's model: its RMS is the final terms' residual
    alpha = example["alpha"]
    for path in example["runs"]:
        run = load_run(path, list(AXES), "T*")
        terms = model["axes"]["ch5_um"]["terms"]
        box = (model["axes"]["ch5_um"]["intercept"] + terms[0]["coef"] * run.column("T11")
               + terms[1]["coef"] * lag(run.column("T16"), alpha))
        stages = summary["runs"][path.stem]["ch5_um"]["stages_rms_um"]
        assert stages[-1]["box"] and not stages[-1]["dropped"]
        assert stages[-1]["rms_um"] == pytest.approx(
            np.sqrt(np.mean((run.target("ch5_um") - box) ** 2)), rel=1e-6)
        assert [s["dropped"] for s in stages] == [False, False, True, False]
        # the effects by the names model.json gives them (the demo counts those kept)
        assert [s["effect"] for s in stages] == [None, "lag(T16, tau=1800s)",
                                                 "T05 + square(T05)", None]
        assert summary["runs"][path.stem]["ch5_um"]["residual_rms_um"]["our model"] == \
            pytest.approx(stages[-1]["rms_um"])


def test_ec_caption_says_the_cap_decided(budget_model):
    from thermal_comp.host.analysis.report_story import count_rule

    model, report = budget_model
    # S_i is smallest at 5 sensors, the cap is 2: the cap decided, not the minimum
    assert count_rule(model["axes"]["ch3_um"]["selection"], model) == "cap"
    assert count_rule(model["axes"]["ch5_um"]["selection"], model) == "min"
    page = report.index.read_text()
    assert "the --max-sensors cap of 2: the out-of-fold error S<sub>i</sub> is smallest at 5 " \
           "sensors (1.5 µm against 3 µm at 2)" in page


def test_fold_stages_come_from_the_effects_evidence_and_are_drawn(tmp_path):
    from thermal_comp.host.analysis import plots
    from thermal_comp.host.analysis.report_story import fold_stages

    axis = {"effects": [
        {"name": "lag(T05)", "rmse_before_um": 3.0, "rmse_after_um": 2.0,
         "evidence": {"fold_rmse_before_um": [2.5, 3.4], "fold_rmse_after_um": [1.8, 2.2]}},
        {"name": "T03 + square(T03)", "rmse_before_um": 2.0, "rmse_after_um": 1.5,
         "dropped_for_channels": True,
         "evidence": {"fold_rmse_before_um": [1.8, 2.2], "fold_rmse_after_um": [1.4, 1.6]}}]}
    rows = fold_stages(axis)
    assert [r["stage"] for r in rows] == ["baseline", "+ lag(T05)", "+ T03 + square(T03)"]
    assert [r["rmse_um"] for r in rows] == [3.0, 2.0, 1.5]
    assert rows[0]["folds_um"] == [2.5, 3.4] and rows[2]["dropped"]
    assert fold_stages({"effects": [{"name": "x", "evidence": {}}]}) == []  # nothing recorded
    fig = plots.fold_errors("dz_um", [r["stage"] for r in rows], [r["rmse_um"] for r in rows],
                            [r["folds_um"] for r in rows], [r["dropped"] for r in rows])
    fig.savefig(tmp_path / "f.png")
    pixels = mpimg.imread(tmp_path / "f.png")
    assert float(pixels[..., :3].std()) > 0.05


def test_run_figure_draws_the_promise_as_a_band_and_ec_figure_the_fold_bars():
    from matplotlib.collections import LineCollection

    from thermal_comp.host.analysis import plots

    t = np.arange(100) * 60.0
    meas = np.sin(t / 900.0)
    fig = plots.run_fit("day", "dz_um", t, meas, {"our model": 0.9 * meas},
                        (1.5, [1.0, 2.0]))
    bottom = fig.axes[1]
    labels = bottom.get_legend_handles_labels()[1]
    assert any(lb.startswith("promised for an unseen day: ±1.50 µm RMS (folds 1.00–2.00 µm")
               for lb in labels)
    # the band's corners in data units (a Rectangle or a Polygon, by matplotlib version)
    ys = np.concatenate([p.get_patch_transform().transform(p.get_path().vertices)[:, 1]
                         for p in bottom.patches])
    assert ys.min() == pytest.approx(-1.5) and ys.max() == pytest.approx(1.5)
    assert {round(ln.get_ydata()[0], 6) for ln in bottom.lines if ln.get_linestyle() == ":"} \
        == {-2.0, 2.0}
    assert not plots.run_fit("day", "dz_um", t, meas, {"m": meas}).axes[1].patches
    ec = plots.ec_curve("dz_um", [1.0, 0.8, 0.9], 2, errors=[3.0, 2.0, 2.2], rule="min",
                        fold_errors=[[2.5, 3.4], [1.5, 2.4], [2.0, 2.4]])
    bars = [c for a in ec.axes for c in a.collections if isinstance(c, LineCollection)]
    segs = np.concatenate([np.asarray(s) for c in bars for s in c.get_segments()])
    np.testing.assert_allclose(sorted(set(segs[:, 1].round(6))),
                               [1.5, 2.0, 2.4, 2.5, 3.4])


def test_the_axis_table_says_which_axes_were_fitted_as_bending():
    from thermal_comp.host.analysis.report import fit_label

    assert fit_label({"family": "ridge", "even_warming_penalty": 3.0}) == "ridge, bending"
    assert fit_label({"family": "ridge", "even_warming_penalty": 0.0}) == "ridge"
    assert fit_label({"family": "ols"}) == "ols"  # a model trained before --bending
    assert fit_label({}) is None


@pytest.fixture(scope="module")
def ridge_report(example, tmp_path_factory):
    """The example with ch5 as host train writes a ridge: T16 selected, T11 read on a free
    channel (fit.free_channels_read), the lag effect dropped by the box's ridge, every sensor
    a c-means group of its own; its coefficients a ridge on the training half."""
    import copy

    from thermal_comp.contract.terms import Term
    from thermal_comp.host.analysis.metrology import ridge_refit, training_design

    model = copy.deepcopy(example["model"])
    ch5 = model["axes"]["ch5_um"]
    sel = ch5["selection"]
    sel["sensors"] = ["T16"]
    sel["groups"] = [[s] for s in sel["correlations"]]
    train = load_run(example["runs"][0], list(AXES), "T*")
    terms = [Term.from_json(t) for t in ch5["terms"]]
    design = training_design("ch5_um", terms, [train], PERIOD_S)
    fit = ridge_refit(design.X, design.y, 1e-3, [True, True])
    ch5["intercept"] = fit.intercept
    for t, c in zip(ch5["terms"], fit.coef, strict=True):
        t["coef"] = float(c)
    ch5["fit"] = {"family": "ridge-baseline", "alpha": 1e-3, "free_channels_read": ["T11"],
                  "prefilter_tau_s": 0.0}
    ch5["effects"][0]["dropped_by_box_ridge"] = True
    ch5["effects_rejected"] = "the box's ridge is not 10 % lower on its own folds with them"
    model["training"]["groups"] = 10
    path = tmp_path_factory.mktemp("ridge") / "model.json"
    path.write_text(json.dumps(model))
    out = tmp_path_factory.mktemp("ridge_out")
    return model, build_report(path, example["runs"], out, peers=False, quiet=True)


def test_the_equation_gives_gains_with_their_fold_spread_and_errors_only_for_ols(
        example, ridge_report):
    model, report = ridge_report
    summary = json.loads((report.out_dir / "summary.json").read_text())
    tables = {c["axis"]: c for c in summary["coefficients"]}
    ols, ridge = tables["ch3_um"], tables["ch5_um"]
    assert ols["least_squares"] and not ridge["least_squares"]
    # the steady-state gain of a sensor read through a lag is that lag's coefficient
    terms = model["axes"]["ch5_um"]["terms"]
    gains = {g["sensor"]: g for g in ridge["sensors"]}
    assert gains["T16"]["steady_um_per_k"] == pytest.approx(terms[1]["coef"])
    assert gains["T16"]["immediate_um_per_k"] == 0.0
    assert gains["T16"]["modes"] == [{"tau_s": TAU_S, "amplitude_um_per_k": terms[1]["coef"]}]
    assert gains["T11"]["steady_um_per_k"] == pytest.approx(terms[0]["coef"])
    # the ridge reproduced from the training runs, then refitted without each of 3 blocks
    assert ridge["refit_relative_difference"] < 1e-9
    assert ridge["folds"] == {"scheme": "time-blocked (3 contiguous blocks of one run)",
                              "count": 3}
    assert len(gains["T11"]["fold_steady_um_per_k"]) == 3
    assert 1.0 < ridge["effective_dof"] < 3.0
    page = report.index.read_text()
    ch5_part = page[page.index("<h3>ch5_um"):page.index("</details>", page.index("<h3>ch5_um"))]
    ch3_part = page[page.index("<h3>ch3_um"):page.index("<h3>ch5_um")]
    assert "effective degrees of freedom" in ch5_part and "VIF" not in ch5_part
    assert "standard error" not in ch5_part and "(±" not in ch5_part
    assert "standard error (AR(1))" in ch3_part and "<th>VIF</th>" in ch3_part
    assert "steady-state gain" in ch5_part and "τ = 1800 s" in ch5_part


def test_captions_name_why_an_effect_was_dropped_and_where_a_sensor_came_from(ridge_report):
    _, report = ridge_report
    page = html.unescape(report.index.read_text())
    assert "Why each was added: ." not in page
    assert ("The box's model runs none of the effects the search added. Dashed grey, added "
            "by the search on this evidence but dropped because the box's ridge is not "
            "10 % lower on its own folds with the effects: <b>lag(T16, tau=1800s)</b>") in page
    assert "no channel left" not in page.split("effects_fl_first_ch5_um")[0].split(
        'id="effects_fl_first_ch5_um"')[-1]
    caption = re.search(r'<figure id="selection_ch5_um">.*?</figure>', page, re.S).group(0)
    assert "Brought in by the effects" not in caption
    assert "Read by the box's ridge on channels the selection left free" in caption
    assert "fit.free_channels_read" in caption and ": T11." in caption
    assert "Each of the 16 candidate sensors is a group of its own" in caption
    assert "--groups 10 is not below 16" in caption
    # no table of one-member groups under it
    table_after = page[page.index('<figure id="selection_ch5_um">'):]
    assert not table_after.split("</figure>", 1)[1].lstrip().startswith("<table><tr><th>group")


class _Captions(HTMLParser):
    """Each figcaption's text, without its bold title and its file link."""

    def __init__(self) -> None:
        super().__init__()
        self.captions: list[str] = []
        self._depth: list[str] = []
        self._in = False

    def handle_starttag(self, tag, attrs):
        if tag == "figcaption":
            self._in, self.captions = True, [*self.captions, ""]
        elif self._in:
            self._depth.append(tag)

    def handle_endtag(self, tag):
        if tag == "figcaption":
            self._in = False
        elif self._in and self._depth:
            self._depth.pop()

    def handle_data(self, data):
        if self._in and not (self._depth and self._depth[-1] in ("a",)) and \
                not (len(self._depth) == 1 and self._depth[0] == "b" and not self.captions[-1]):
            self.captions[-1] += data


def _chromium_screenshot(page: Path, png: Path, profile: Path) -> subprocess.CompletedProcess:
    cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
           "--no-first-run", "--disable-background-networking", "--disable-component-update",
           "--disable-sync", f"--user-data-dir={profile}", "--window-size=1280,2400",
           f"--screenshot={png}", page.as_uri()]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120)


@pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed (CI installs it: "
                                             "scripts/install-system-deps.sh)")
@pytest.mark.parametrize("which", ["rendered", "ridge_report"])
def test_report_in_headless_chromium_has_no_clipped_legend_or_label_and_no_empty_caption(
        which, request, tmp_path):
    report = request.getfixturevalue(which)
    report = report[1] if isinstance(report, tuple) else report
    # the browser draws the page as a reader sees it
    png = tmp_path / "page.png"
    done = _chromium_screenshot(report.index, png, tmp_path / "profile")
    assert done.returncode == 0 and png.is_file(), done.stderr[-2000:]
    pixels = mpimg.imread(png)
    assert pixels.shape[:2] == (2400, 1280) and float(pixels[..., :3].std()) > 0.05
    # every figure: its legends, titles, labels and tick labels inside the PNG, checked when
    # it was saved (plots.clipped_artists)
    summary = json.loads((report.out_dir / "summary.json").read_text())
    assert summary["figures_clipped"] == {}
    assert all(not f.clipped for f in report.figures)
    # every caption says something, and no list in it is empty
    parser = _Captions()
    parser.feed(report.index.read_text())
    assert len(parser.captions) == len(report.figures)
    for text in parser.captions:
        body = " ".join(text.split()).strip(" ()")
        assert len(body) > 40, text
        assert ": ." not in body and ":." not in body and "()" not in body, body


def test_the_clip_check_finds_a_legend_wider_than_the_figure(tmp_path):
    from matplotlib.figure import Figure as MplFigure

    from thermal_comp.host.analysis import plots

    fig = MplFigure(figsize=plots.WIDE, layout="constrained")
    ax = fig.add_subplot()
    for k in range(4):
        ax.plot([0, 1], [k, k + 1], label="+ rate(T08, tau=600s) (dropped: the box's ridge is "
                                          "not 10 % lower on its own folds): RMS 0.99 µm")
    fig.legend(fontsize=8, loc="outside lower center", ncol=2)
    clipped = plots.save_png(fig, tmp_path / "wide.png")
    assert len(clipped) == 1 and clipped[0].startswith("figure legend 0 at x -")
    # the effects figure wraps the same labels and grows to hold them
    t = np.arange(100) * 60.0
    stages = [(f"+ rate(T08, tau={k}00s) (dropped: the box's ridge is not 10 % lower on its "
               "own folds with the effects)", np.sin(t / 600 + k)) for k in range(5)]
    fig = plots.residual_steps("run", "dz_um", t, stages, [False, True, True, True, False])
    assert plots.save_png(fig, tmp_path / "effects.png") == []


def test_a_service_day_is_drawn_with_host_evaluates_numbers(example, tmp_path, capsys):
    # issue 42: static, updated and probe-only with the probe times marked, from synthesised
    # readings (the options) and from a run's logged probe_<axis> column
    from thermal_comp.host.analysis import load_for_model
    from thermal_comp.host.analysis.service import readings_for, service_of
    from thermal_comp.host.service import ProbePlan

    plan = ProbePlan(3600.0, 0.5, 3)
    run = example["runs"][1]
    report = build_report(example["model_path"], [run], tmp_path / "synth", peers=False,
                          quiet=True, probes=plan)
    figs = [f for f in report.figures if f.section == "service"]
    assert [f.file for f in figs] == [f"service_fl_second_{a}.png" for a in AXES]
    assert all(not f.clipped for f in figs)  # plots.save_png's check
    for f in figs:
        assert (tmp_path / "synth" / f.file).read_bytes().startswith(PNG_SIGNATURE)
        assert "accepted" in f.caption and "probe-only" in f.caption and "static" in f.caption
    loaded = load_for_model(run, example["model"])
    readings = readings_for(example["model"], loaded, plan)
    expected = service_of(example["model"], loaded, readings)  # host evaluate's computation
    got = report.summary["service"]["fl_second"]
    assert got["probes"] == readings.source
    for axis in AXES:
        for key in ("rmse_um", "static_rmse_um", "probe_only_rmse_um", "probes", "refused"):
            assert got["axes"][axis][key] == pytest.approx(expected[axis][key], rel=1e-12)
        assert f"{got['axes'][axis]['rmse_um']:.2f}" in figs[AXES.index(axis)].caption
    page = report.index.read_text()
    assert "A day in service" in page and "service_fl_second_ch3_um" in page

    # a logged column, used as it is: only that axis gets a service day
    logged = tmp_path / "logged.csv"
    lines = run.read_text().splitlines()
    head = lines[0].split(",")
    lines[0] += ",probe_ch3_um"
    col = head.index("ch3_um")
    for k in range(1, len(lines)):
        lines[k] += "," + (lines[k].split(",")[col] if k % 120 == 0 else "")
    logged.write_text("\n".join(lines) + "\n")
    report = build_report(example["model_path"], [logged], tmp_path / "logged", peers=False,
                          quiet=True)
    assert [f.file for f in report.figures if f.section == "service"] == [
        "service_logged_ch3_um.png"]
    assert report.summary["service"]["logged"]["axes"]["ch3_um"]["probes"] == (
        len(lines) - 1) // 120

    # the command line takes the probe options and prints the numbers
    assert host_main(["report", str(example["model_path"]), "--runs", str(run), "-o",
                      str(tmp_path / "cli"), "--no-peers", "--probe-every", "60min",
                      "--probe-seed", "3"]) == 0
    out = capsys.readouterr().out
    assert "in service on fl_second" in out and "probe-only" in out

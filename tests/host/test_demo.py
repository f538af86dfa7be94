"""The demo's own machinery: a failing step stops it with the command and its output, and the
closing table's numbers are the summary's (the full demo runs as `make demo`, not in tests)."""

from __future__ import annotations

import io
import sys

import pytest

from thermal_comp.host.demo import Demo, DemoFailed, print_error_table


def test_a_failing_command_stops_with_its_output_and_exit_code():
    demo = Demo(out=io.StringIO())
    demo.step("a step that fails")
    with pytest.raises(DemoFailed) as info:
        demo.run([sys.executable, "-c",
                  "import sys; print('partial result'); print('why it broke', file=sys.stderr); "
                  "sys.exit(3)"])
    text = str(info.value)
    assert "a step that fails" in text and "exited with code 3" in text
    assert "partial result" in text and "why it broke" in text


def test_a_missing_program_is_a_clear_failure():
    demo = Demo(out=io.StringIO())
    demo.step("needs a tool")
    with pytest.raises(DemoFailed, match="needs a tool: cannot run no-such-tool-xyz"):
        demo.run(["no-such-tool-xyz"])


def test_error_table_shows_raw_baseline_box_reduction_and_effects_kept():
    out = io.StringIO()
    summary = {"runs": {"unseen_run": {"dz_um": {
        "raw_rms_um": 20.0, "in_training": False,
        "residual_rms_um": {"our model": 1.4, "OLS, all sensors": 3.0}}}}}
    print_error_table(Demo(out=out), [("simulated", summary)])
    row = [ln for ln in out.getvalue().splitlines() if "unseen_run" in ln][0]
    assert row.split() == ["simulated", "unseen_run", "dz_um", "no", "20.00", "µm", "—", "1.40",
                           "µm", "93", "%", "—"]  # 100 * (1 - 1.4 / 20) = 93
    # the loop found two effects, the box kept one; the baseline is the report's own column
    summary["runs"]["unseen_run"]["dz_um"]["stages_rms_um"] = [
        {"stage": "baseline (temperatures only)", "rms_um": 2.5, "effect": None,
         "dropped": False},
        {"stage": "+ lag(T01, tau=600s)", "rms_um": 1.6, "effect": "lag(T01, tau=600s)",
         "dropped": False},
        {"stage": "+ rate(T02, tau=600s) (dropped: ...)", "rms_um": 1.5,
         "effect": "rate(T02, tau=600s)", "dropped": True},
        {"stage": "the box's model (ridge)", "rms_um": 1.4, "effect": None, "dropped": False}]
    summary["runs"]["unseen_run"]["dz_um"]["baseline_rms_um"] = 2.5
    out.truncate(0)
    print_error_table(Demo(out=out), [("simulated", summary)])
    row = [ln for ln in out.getvalue().splitlines() if "unseen_run" in ln][0]
    assert row.split()[4:] == ["20.00", "µm", "2.50", "µm", "1.40", "µm", "93", "%", "1", "of",
                               "2"]
    # an axis without effects still shows where the loop started
    del summary["runs"]["unseen_run"]["dz_um"]["stages_rms_um"]
    summary["runs"]["unseen_run"]["dz_um"]["baseline_rms_um"] = 3.25
    out.truncate(0)
    print_error_table(Demo(out=out), [("simulated", summary)])
    row = [ln for ln in out.getvalue().splitlines() if "unseen_run" in ln][0]
    assert row.split()[6:8] == ["3.25", "µm"] and row.split()[-1] == "—"


def test_outside_a_checkout_the_demo_says_what_it_needs(monkeypatch, tmp_path, capsys):
    import thermal_comp.host.demo as demo
    from thermal_comp.contract import checkout

    monkeypatch.setenv(checkout.ENV, str(tmp_path))  # as a wheel: no examples, no firmware
    assert demo.main([]) == 2
    err = capsys.readouterr().err
    assert "needs the project's git checkout" in err and "firmware/Makefile" in err


def test_training_line_says_each_reason_once_for_the_effects_the_box_does_not_run():
    from thermal_comp.host.demo import print_training

    out = io.StringIO()
    doc = {"axes": {"dz_um": {"sensors": ["T1", "T2"], "validation_rmse_um": 0.3,
                              "raw_rms_um": 9.0, "fit": "ridge-baseline"}}}
    model = {"axes": {"dz_um": {"effects": [
        {"name": "lag(T1, tau=600s)", "dropped_by_box_ridge": True},
        {"name": "rate(T2, tau=1200s)", "dropped_by_box_ridge": True},
        {"name": "speed(spindle_rpm)", "dropped_for_channels": True}]}}}
    print_training(Demo(out=out), doc, model)
    line = out.getvalue()
    assert line.count("the box's ridge is not 10 % lower") == 1
    assert ("not in the box's model: lag(T1, tau=600s), rate(T2, tau=1200s) (the box's ridge"
            in line)
    assert "; speed(spindle_rpm) (no box channel left for its sensor)" in line


def _fl_ch5(ridge_nested: float = 10.41) -> tuple[dict, dict]:
    """The demo's FL ch5 on the unseen 5000 rpm cycle, cut down to what the table reads: the
    box's ridge 5.04 µm against its baseline's 4.10 µm."""
    summary = {"model": "/nonexistent/model.json",
               "runs": {"fl_24-32h": {"ch5_um": {
                   "raw_rms_um": 27.78, "in_training": False, "baseline_rms_um": 4.10,
                   "residual_rms_um": {"our model": 5.04}}}},
               "outside_training": {"fl_24-32h": [{"input": "T09"}, {"input": "T01"}]},
               "coefficients": [{"axis": "ch5_um", "warnings": [
                   {"name": "gain sign undetermined", "text": "T01 flips"}]}]}
    model = {"axes": {"ch5_um": {
        "terms": [{"kind": "temp", "source": s, "coef": 1.0} for s in ("T01", "T09")],
        "baseline": {"terms": [{"kind": "temp", "source": "T01", "coef": 1.0}]},
        "effects": [{"name": "rate(T09, tau=1200s)", "dropped_by_box_ridge": True}],
        "effects_rejected": "its ridge is 7.95 um out of fold with them and 7.95 um without",
        "metrics": {"promised_rmse_um": 26.16, "promise": "RMS on an unseen day ≤ 26.16 µm"},
        "fit": {"family": "ridge-baseline", "requested": "ridge", "free_channels_read": ["T09"],
                "nested": {"rmse_um": {"ols": 8.70, "baseline": 9.80, "ridge": 10.26,
                                       "ridge-baseline": ridge_nested},
                           "fold_rmse_um": {"baseline": [6.37, 8.64, 13.15],
                                            "ridge-baseline": [11.95, 11.13, 7.65]}}}}}}
    return summary, model


def test_an_unseen_row_where_the_box_loses_to_its_baseline_is_said_and_explained():
    summary, model = _fl_ch5()
    out = io.StringIO()
    print_error_table(Demo(out=out), [("FL_THERMAL", summary)], {"FL_THERMAL": model})
    text = out.getvalue()
    row = next(ln for ln in text.splitlines() if "fl_24-32h" in ln and "ch5_um" in ln)
    assert "WORSE than baseline (1)" in row
    words = " ".join(text.split())  # the explanation is wrapped
    assert "(1) FL_THERMAL fl_24-32h, ch5_um: on this unseen run the box's model is WORSE" in words
    assert "5.04 vs 4.10 µm RMS, +23 %" in words
    # the reason from model.json: the family, what chose it, what nested validation said
    assert "it runs ridge-baseline" in words and "chosen by --fit ridge (host train's default)" \
        in words
    assert ("had already ranked it behind the baseline: ridge-baseline 10.41 µm RMS (folds "
            "11.95, 11.13, 7.65), the baseline 9.80 µm (folds 6.37, 8.64, 13.15), the baseline "
            "better in 2 of 3 folds; lowest: ols") in words
    assert "rate(T09, tau=1200s), are not run" in words and "7.95 um without" in words
    assert "reads T09 on free channels" in words
    assert "beyond their training range (T09 read by the box's model only)" in words
    assert "'gain sign undetermined': T01 flips" in words
    assert "still within its promise (RMS on an unseen day ≤ 26.16 µm)" in words

    # nested validation had the box's family ahead: then the folds did not foresee it
    summary, model = _fl_ch5(ridge_nested=7.0)
    out = io.StringIO()
    print_error_table(Demo(out=out), [("FL_THERMAL", summary)], {"FL_THERMAL": model})
    words = " ".join(out.getvalue().split())
    assert "ranked it ahead of the baseline, so the training folds did not foresee this" in words

    # without model.json it still says so, and that it cannot say why
    out = io.StringIO()
    print_error_table(Demo(out=out), [("FL_THERMAL", summary)])
    words = " ".join(out.getvalue().split())
    assert "WORSE than its baseline (5.04 vs 4.10" in words and "no reason can be given" in words


def test_no_row_where_the_box_loses_to_its_baseline_on_an_unseen_run_passes_silently():
    summary, model = _fl_ch5()
    row = summary["runs"]["fl_24-32h"]["ch5_um"]
    cases = [(False, 5.04, 4.10, True), (False, 4.0, 4.10, False), (True, 5.04, 4.10, False),
             (False, 5.04, None, False)]
    for in_training, ours, base, said in cases:
        row.update(in_training=in_training, baseline_rms_um=base,
                   residual_rms_um={"our model": ours})
        out = io.StringIO()
        print_error_table(Demo(out=out), [("FL_THERMAL", summary)], {"FL_THERMAL": model})
        assert ("WORSE" in out.getvalue()) is said, (in_training, ours, base)

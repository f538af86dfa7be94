"""The demo's own machinery: a failing step stops it with the command and its output, and the
closing table's numbers are the summary's (the full demo runs as `make demo`, not in tests)."""

from __future__ import annotations

import io
import sys

import pytest

from host.demo import Demo, DemoFailed, print_error_table


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
    import host.demo as demo

    monkeypatch.setattr(demo, "ROOT", tmp_path)  # an installed wheel: no examples, no firmware
    assert demo.main([]) == 2
    err = capsys.readouterr().err
    assert "needs a git checkout" in err and "firmware/Makefile" in err


def test_training_line_says_each_reason_once_for_the_effects_the_box_does_not_run():
    from host.demo import print_training

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

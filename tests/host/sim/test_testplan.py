"""The NC program of a thermal test, parsed with pygcode and executed by a minimal interpreter
written here: its speed schedule and measurement times must be the protocol's."""

from __future__ import annotations

import numpy as np
import pytest
from pygcode import Line

from thermal_comp.host.cli import main
from thermal_comp.host.sim import PlanError, ThermalTestPlan, build_program, parse_duration


def execute(text: str, dialect: str = "rs274") -> dict:
    """Run the program on paper: spindle state over time, trigger times, orientation."""
    t = 0.0
    rpm, on, oriented = 0.0, False, False
    spans: list[tuple[float, float, float]] = []  # (start, end, rpm actually turning)
    triggers: list[tuple[float, bool, bool]] = []  # (time, spindle stopped, oriented)
    ended = False
    lines = text.splitlines()
    assert lines[0] == "%" and lines[-1] == "%"
    for raw in lines[1:-1]:
        line = Line(raw)
        assert not ended, "blocks after M30"
        words = {str(w) for w in line.block.modal_params}
        dwell = None
        for g in line.block.gcodes:
            name = type(g).__name__
            if name == "GCodeSpindleSpeed":
                rpm = float(g.word.value)
            elif name == "GCodeStartSpindleCW":
                on, oriented = True, False
            elif name == "GCodeStopSpindle":
                on = False
            elif name == "GCodeOrientSpindle":
                on, oriented = False, True
            elif name == "GCodeDwell":
                dwell = g
            elif name == "GCodeEndProgramPalletShuttle":
                ended = True
        if "M100" in words or "M123" in words:
            triggers.append((t, not on, oriented))
        if dwell is not None:
            if dialect == "rs274":
                seconds = float(dwell.params["P"].value)
            else:  # fanuc: pygcode leaves X as a loose word
                assert "P" not in dwell.params
                seconds = float(next(w.value for w in line.block.modal_params if w.letter == "X"))
            spans.append((t, t + seconds, rpm if on else 0.0))
            t += seconds
    assert ended and not on
    return {"spans": spans, "triggers": triggers, "end": t}


def speed_at(spans, tau):
    for a, b, r in spans:
        if a <= tau < b:
            return r
    return 0.0


@pytest.mark.parametrize("protocol", ["constant", "step", "random", "sine"])
@pytest.mark.parametrize("dialect", ["rs274", "fanuc"])
def test_executed_schedule_and_measurements_match_the_protocol(protocol, dialect):
    prog = build_program(protocol, 8000.0, hours=2.0, cool_hours=1.0, seed=4)
    every, stop = 300.0, 10.0
    plan = ThermalTestPlan(prog, every, stop, "M100", dialect)
    run = execute(plan.render(), dialect)
    # measurements: the cold reference at 0, then every 5 min, spindle stopped and oriented
    times = [tr[0] for tr in run["triggers"]]
    np.testing.assert_allclose(times, np.arange(0, 3 * 3600 + 1, every))
    assert all(stopped and oriented for _, stopped, oriented in run["triggers"])
    assert run["end"] == pytest.approx(stop + prog.duration_s)
    # the spindle turns at the protocol's speed except during the 10 s stops
    for tau in np.arange(0.5, run["end"], 1.0):
        t = tau - stop  # schedule time after the reference measurement
        in_stop = t < 0 or (t % every) >= every - stop
        expected = 0.0 if in_stop else float(prog.rpm_at(t))
        assert speed_at(run["spans"], tau) == expected, (protocol, tau)
    assert max(r for *_, r in run["spans"]) <= 8000.0


def test_cli_writes_the_issue_example(tmp_path, capsys):
    out = tmp_path / "thermal_test.nc"
    assert main(["testplan", "--protocol", "step", "--max-rpm", "8000", "--hours", "8",
                 "--cool-hours", "8", "--measure-every", "5min", "--trigger", "M123",
                 "-o", str(out)]) == 0
    text = out.read_text()
    run = execute(text)
    assert len(run["triggers"]) == 16 * 12 + 1
    assert "(T 0:15:00 - 0:30:00 S4000 RUN)" in text  # the schedule is listed in comments
    assert text.splitlines()[-2].startswith("M30") and "M5" in text.splitlines()[-3]
    assert "193 measurements" in capsys.readouterr().out


@pytest.mark.parametrize("kwargs, message", [
    ({"measure_every_s": 300.0, "measure_s": 300.0}, "does not fit"),
    ({"measure_every_s": 420.0}, "not a whole number"),
    ({"trigger": "M19"}, "already means"),
    ({"trigger": "G4"}, "M-code"),
])
def test_schedules_that_do_not_fit_are_refused(kwargs, message):
    with pytest.raises(PlanError, match=message):
        ThermalTestPlan(build_program("step", 8000.0, hours=2.0, cool_hours=1.0), **kwargs)


def test_speed_change_inside_a_measurement_stop_is_refused():
    prog = build_program("step", 8000.0, hours=2.0, cool_hours=1.0, step_minutes=9.9)
    with pytest.raises(PlanError, match="inside the measurement stop"):
        ThermalTestPlan(prog, 600.0, 10.0)  # the first change at 594 s falls in [590, 600)
    with pytest.raises(ValueError, match="above --max-rpm"):
        build_program("constant", 8000.0, rpm=8001.0)


def test_cli_refuses_speed_above_max(tmp_path, capsys):
    out = tmp_path / "t.nc"
    assert main(["testplan", "--rpm", "9000", "--max-rpm", "8000", "-o", str(out)]) == 2
    assert "above --max-rpm 8000" in capsys.readouterr().err and not out.exists()


def test_durations_parse():
    assert parse_duration("5min", "x") == 300.0
    assert parse_duration("1.5h", "x") == 5400.0
    assert parse_duration("10", "x") == 10.0
    with pytest.raises(PlanError, match="cannot read"):
        parse_duration("five", "--measure-every")


def _linuxcnc_plan(trigger: str) -> ThermalTestPlan:
    prog = build_program("step", 8000.0, hours=1.0, cool_hours=0.5)
    return ThermalTestPlan(prog, 900.0, 10.0, trigger, "linuxcnc")


def test_linuxcnc_digital_output_trigger_pulses_for_each_stop():
    plan = _linuxcnc_plan("M64 P2")
    lines = plan.render().splitlines()
    on = [i for i, line in enumerate(lines) if line.startswith("M64 P2")]
    assert len(on) == plan.n_intervals + 1 == 7
    for i in on:  # the output for exactly the measurement dwell
        assert lines[i + 1] == "G4 P10." and lines[i + 2] == "M65 P2"
        # stopped and oriented: the last spindle word before the trigger is M19 R0
        last = [line for line in lines[:i] if line.startswith(("M3", "M5", "M19"))][-1]
        assert last == "M19 R0", (i, last)
    assert "M19" not in [line.strip() for line in lines]  # LinuxCNC ignores a bare M19
    assert plan.digital_output == 2


def test_linuxcnc_user_m_code_gets_the_measurement_number():
    plan = _linuxcnc_plan("M100")
    calls = [line.split(" (")[0] for line in plan.render().splitlines()
             if line.startswith("M100")]
    assert calls == [f"M100 P{k}" for k in range(plan.n_intervals + 1)]
    assert plan.digital_output is None


@pytest.mark.parametrize("dialect, trigger", [("rs274", "M100"), ("fanuc", "M100"),
                                              ("linuxcnc", "M64 P0"), ("linuxcnc", "M100")])
def test_comments_are_never_nested(dialect, trigger):
    """LinuxCNC refuses a program with a '(' inside a comment ("Nested comment found")."""
    prog = build_program("random", 8000.0, hours=1.0, cool_hours=0.5, seed=2)
    for line in ThermalTestPlan(prog, 300.0, 10.0, trigger, dialect).render().splitlines():
        depth = 0
        for ch in line:
            depth += {"(": 1, ")": -1}.get(ch, 0)
            assert 0 <= depth <= 1, line
        assert depth == 0, line


@pytest.mark.parametrize("dialect, trigger, message", [
    ("rs274", "M64 P0", "only with --dialect linuxcnc"),
    ("linuxcnc", "M65 P0", "the only trigger with a P word"),
    ("linuxcnc", "M64 P64", "P0..P63"),
    ("linuxcnc", "M99", "M100-M199"),
    ("linuxcnc", "M200", "M100-M199"),
    ("linuxcnc", "G4", "M100 or M64 P0"),
])
def test_triggers_linuxcnc_cannot_do_are_refused(dialect, trigger, message):
    with pytest.raises(PlanError, match=message):
        ThermalTestPlan(build_program("step", 8000.0, hours=2.0, cool_hours=1.0),
                        trigger=trigger, dialect=dialect)


def test_cli_writes_a_linuxcnc_program(tmp_path, capsys):
    out = tmp_path / "thermal_test.ngc"
    assert main(["testplan", "--protocol", "constant", "--hours", "1", "--cool-hours", "1",
                 "--measure-every", "10min", "--dialect", "linuxcnc", "--trigger", "m64p1",
                 "-o", str(out)]) == 0
    text = out.read_text()
    assert text.count("M64 P1 (MEASUREMENT") == 13 and text.count("\nM65 P1\n") == 13
    assert "wrote" in capsys.readouterr().out

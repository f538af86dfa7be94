"""A run in another unit is refused with what it looks like and what to pass, and read when the
unit is given (issue 43: degF, mm, minutes, nm, beside kelvin and milliseconds); the refusals
of a missing column say where the name came from, in one phrasing with "did you mean";
day-first dates are read, or refused with a hint when they could be either."""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import numpy as np
import pytest

from thermal_comp.contract.errors import InputError
from thermal_comp.contract.model_file import write_model
from thermal_comp.host.cli import main as host_main
from thermal_comp.host.io import CsvFormat, RunFormatError, load_run, read_table, write_run

ROOT = Path(__file__).resolve().parents[3]
RUN = ROOT / "examples" / "sim_constant.csv"
TARGETS = ["dx_um", "dz_um"]


@pytest.fixture(scope="module")
def columns():
    header, data, _ = read_table(RUN)
    return data[:, 0].copy(), {n: data[:, i].copy() for i, n in enumerate(header) if i}


def written(tmp: Path, name: str, columns, *, temp=None, disp=None, time=None) -> Path:
    """The example run rewritten in another unit (each conversion written out here)."""
    t, cols = columns
    cols = {n: v.copy() for n, v in cols.items()}
    for n in cols:
        if n.startswith("T") and temp is not None:
            cols[n] = temp(cols[n])
        if n.endswith("_um") and disp is not None:
            cols[n] = disp(cols[n])
    path = tmp / f"{name}.csv"
    write_run(path, time(t) if time is not None else t, cols, precision=10)
    return path


CASES = {
    # name: (conversion, what the refusal says it looks like, the option that reads it)
    "degF": (dict(temp=lambda c: c * 1.8 + 32), "look like degF", "--temp-unit F",
             CsvFormat(temp_unit="F")),
    "mm": (dict(disp=lambda u: u / 1000), "look like millimetres", "--disp-unit mm",
           CsvFormat(disp_unit="mm")),
    "nm": (dict(disp=lambda u: u * 1000), "look like nanometres", "--disp-unit nm",
           CsvFormat(disp_unit="nm")),
    "minutes": (dict(time=lambda s: s / 60), "looks like minutes", "--time-unit min",
                CsvFormat(time_unit="min")),
    "hours": (dict(time=lambda s: s / 3600), "looks like minutes", "--time-unit min",
              CsvFormat(time_unit="h")),
    "kelvin": (dict(temp=lambda c: c + 273.15), "looks like kelvin", "--temp-unit K",
               CsvFormat(temp_unit="K")),
    "milliseconds": (dict(time=lambda s: s * 1000), "looks like milliseconds",
                     "--time-unit ms", CsvFormat(time_unit="ms")),
}


@pytest.mark.parametrize("case", list(CASES))
def test_a_run_in_another_unit_is_refused_and_read_when_the_unit_is_given(tmp_path, columns,
                                                                         case):
    convert, looks, option, fmt = CASES[case]
    path = written(tmp_path, case, columns, **convert)
    if case == "hours":  # steps of 1/60: not told from minutes, but refused all the same
        with pytest.raises(RunFormatError) as err:
            load_run(path, TARGETS)
        assert looks in str(err.value)
    else:
        with pytest.raises(RunFormatError) as err:
            load_run(path, TARGETS)
        message = str(err.value)
        assert looks in message and option in message, message
    plain = load_run(RUN, TARGETS)
    read = load_run(path, TARGETS, fmt=fmt)
    np.testing.assert_allclose(read.time_s, plain.time_s, rtol=1e-9, atol=1e-6)
    np.testing.assert_allclose(read.temperatures, plain.temperatures, atol=1e-6)
    np.testing.assert_allclose(read.displacements, plain.displacements, atol=1e-6)


def test_the_default_unit_given_says_the_data_really_is_in_it(tmp_path, columns):
    path = written(tmp_path, "hot", columns, temp=lambda c: c + 40)  # 60..82 degC, all of it
    with pytest.raises(RunFormatError, match="look like degF"):
        load_run(path, TARGETS)
    run = load_run(path, TARGETS, fmt=CsvFormat(temp_unit="C"))
    assert run.temperatures.min() >= 59


def test_nanometres_through_host_train_name_the_unit_not_a_model_json(tmp_path, columns):
    path = written(tmp_path, "nm", columns, disp=lambda u: u * 1000)
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        code = host_main(["train", str(path), "--target", "dz_um", "--out",
                          str(tmp_path / "out")])
    assert code == 2
    assert "look like nanometres" in err.getvalue() and "--disp-unit nm" in err.getvalue()
    assert "model.json" not in err.getvalue() and not (tmp_path / "out").exists()


def test_a_model_that_cannot_be_written_is_not_named_as_written(tmp_path):
    model = {"schema": "thermal-model/1", "tool_version": "0.1.0", "sample_period_s": 1.0,
             "channels": [{"channel": 0, "sensor": "T01", "tc_type": "K", "min_c": -40.0,
                           "max_c": 200.0}],
             "aux": [], "time_max_s": 604800.0,
             "axes": {"dz_um": {"unit": "um", "intercept": 0.0,
                                "terms": [{"kind": "temp", "source": "T01", "coef": 1e5}]}}}
    path = tmp_path / "model.json"
    with pytest.raises(InputError) as err:
        write_model(model, path)
    assert f"{path} (not written)" in str(err.value) and not path.exists()


# ---------------------------------------------------------------- missing columns

@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("units_model")
    out = tmp / "model"
    with contextlib.redirect_stdout(io.StringIO()):
        assert host_main(["train", str(RUN), "--target", "dz_um", "--out", str(out),
                          "--no-effects", "--max-sensors", "2"]) == 0
    return out / "model.json", json.loads((out / "model.json").read_text())


def _stderr(args: list[str]) -> tuple[int, str]:
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = host_main(args)
    return code, err.getvalue()


def test_evaluate_names_the_model_as_the_source_of_a_missing_axis(tmp_path, columns, trained):
    model_path, _ = trained
    t, cols = columns
    path = tmp_path / "no_dz.csv"
    write_run(path, t, {n: v for n, v in cols.items() if n != "dz_um"} | {"dz_mm": cols["dz_um"]})
    code, err = _stderr(["evaluate", str(model_path), str(path)])
    assert code == 2
    assert "missing target column (an axis of the model)" in err and "--target" not in err


def test_one_phrasing_for_a_missing_sensor_with_did_you_mean(tmp_path, columns, trained):
    model_path, model = trained
    used = model["channels"][0]["sensor"]
    t, cols = columns
    renamed = used.lower() + "x"  # T03 -> t03x
    path = tmp_path / "renamed.csv"
    write_run(path, t, {(renamed if n == used else n): v for n, v in cols.items()})
    wanted = f"missing sensor column(s) {used} (did you mean"
    messages = []
    for command in ("evaluate", "diagnose", "report"):
        args = [command, str(model_path), str(path)]
        if command == "report":
            args = ["report", str(model_path), "--runs", str(path), "--out",
                    str(tmp_path / "rep")]
        code, err = _stderr(args)
        assert code == 2, (command, err)
        messages.append(err)
    with pytest.raises(RunFormatError) as err:
        load_run(path, ["dz_um"], sensors=[used])
    messages.append(str(err.value))
    from thermal_comp.host.train import train_model
    from thermal_comp.host.train.training_data import TrainingError

    run = load_run(path, ["dz_um"], sensors="*", aux=["spindle_rpm"])
    run.sensor_names = [n for n in run.sensor_names if n != "T_amb"]
    with pytest.raises(TrainingError) as err:
        train_model([run], ["dz_um"], sensors=[used], effects=False, quiet=True)
    messages.append(str(err.value))
    for message in messages:
        assert wanted in message, message
        assert "the run's columns:" in message


def test_did_you_mean_for_a_target_and_an_aux(tmp_path, columns):
    t, cols = columns
    path = tmp_path / "r.csv"
    write_run(path, t, cols)
    with pytest.raises(RunFormatError, match=r"given by --target\) \(did you mean 'dz_um'\?\)"):
        load_run(path, ["dz_mu"])
    with pytest.raises(RunFormatError, match=r"\(did you mean 'spindle_rpm'\?\)"):
        load_run(path, ["dz_um"], aux=["spindle_rmp"])


# ---------------------------------------------------------------- day-first dates

def _logger(tmp: Path, name: str, stamps: list[str], header: str = "Zeit") -> Path:
    path = tmp / name
    rows = [f"{s};{20 + 0.01 * i:.2f};{21 + 0.02 * i:.2f};{0.1 * i:.1f}"
            for i, s in enumerate(stamps)]
    path.write_text(f"{header};T01;T02;dz_um\n" + "\n".join(rows) + "\n")
    return path


def test_day_first_dates_are_read_as_the_iso_ones(tmp_path):
    iso = [f"2026-12-{d:02d} {h:02d}:00:00" for d in (3, 4) for h in range(0, 24, 2)]
    dots = [f"{d:02d}.12.2026 {h:02d}:00:00" for d in (3, 4) for h in range(0, 24, 2)]
    slashes = [f"{d:02d}/12/2026 {h:02d}:00" for d in (13, 14) for h in range(0, 24, 2)]
    us = [f"12/{d:02d}/2026 {h:02d}:00" for d in (13, 14) for h in range(0, 24, 2)]
    a = load_run(_logger(tmp_path, "iso.csv", iso), ["dz_um"])
    b = load_run(_logger(tmp_path, "dots.csv", dots), ["dz_um"])
    c = load_run(_logger(tmp_path, "slashes.csv", slashes), ["dz_um"])
    d = load_run(_logger(tmp_path, "us.csv", us), ["dz_um"])
    assert a.period_s == 7200.0 and a.time_s[-1] == 23 * 7200.0
    for other in (b, c, d):
        np.testing.assert_array_equal(other.time_s, a.time_s)


def test_ambiguous_or_misplaced_dates_are_refused_with_a_hint(tmp_path):
    either = [f"{d:02d}/{m:02d}/2026 12:00" for d, m in ((1, 2), (2, 2), (3, 2), (4, 2))]
    with pytest.raises(RunFormatError, match="day-first or month-first.*ISO 8601"):
        load_run(_logger(tmp_path, "either.csv", either), ["dz_um"])
    path = tmp_path / "two.csv"
    path.write_text("time_s;Datum;T01;dz_um\n" + "\n".join(
        f"{60 * i};0{i + 1}.12.2026 12:00;20,{i};0,{i}" for i in range(5)) + "\n")
    with pytest.raises(RunFormatError, match="a date and time, in a column that is not the "
                       "time column: name it with --time-col 'Datum'"):
        load_run(path, ["dz_um"])

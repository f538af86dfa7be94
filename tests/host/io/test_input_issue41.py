"""Issue 41: inputs that raised a traceback or were silently accepted become clear errors.

Each case is reproduced on the example runs through ``host`` (exit code 2, one line naming
what is wrong and where) or through the model-file check every command shares.
"""

from __future__ import annotations

import copy
import csv
import json
import shutil
from pathlib import Path

import pytest

from thermal_comp.contract.errors import InputError
from thermal_comp.contract.model_file import ModelFormatError, check_model
from thermal_comp.hil.example_model import default_terms, fit_example_model
from thermal_comp.host.cli import main
from thermal_comp.host.io import RunFormatError, load_run

REPO = Path(__file__).resolve().parents[3]
EX = REPO / "examples"
RUN = EX / "sim_constant.csv"
OTHER = EX / "sim_step.csv"


def _error(capsys, argv: list[str]) -> str:
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err
    return err


def _parse_error(capsys, argv: list[str]) -> str:
    """argparse's refusal of a value: exit 2 with 'argument --x: ...'."""
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    return capsys.readouterr().err


@pytest.fixture(scope="module")
def model() -> dict:
    terms = default_terms(["T01", "T02"], 60.0, "spindle_rpm")
    return fit_example_model(EX / "sim_random.csv", {"dx_um": terms},
                             aux_names=["spindle_rpm"])


@pytest.mark.parametrize("source", [{}, [], 5, None])
def test_a_term_source_that_is_no_name_is_a_format_error(model, source):
    bad = copy.deepcopy(model)
    bad["axes"]["dx_um"]["terms"][0]["source"] = source
    with pytest.raises(ModelFormatError, match=r"axis 'dx_um' term 0 .*source"):
        check_model(bad, "m.json")


@pytest.mark.parametrize("source", [{}, []])
def test_a_term_source_object_through_the_command_line(model, source, tmp_path, capsys):
    bad = copy.deepcopy(model)
    bad["axes"]["dx_um"]["terms"][1]["source"] = source
    path = tmp_path / "m.json"
    path.write_text(json.dumps(bad), encoding="utf-8")
    err = _error(capsys, ["codegen", str(path), "-o", str(tmp_path / "m.h")])
    assert f"{path}: axis 'dx_um' term 1" in err
    assert f"source must be the name of a channel (a string), got {json.dumps(source)}" in err


def test_negative_seed_is_refused(capsys):
    err = _parse_error(capsys, ["train", str(RUN), "--target", "dx_um", "--seed", "-1"])
    assert "argument --seed: -1 must be between 0 and" in err


def test_a_seed_numpy_cannot_take_is_refused(capsys):
    err = _parse_error(capsys, ["train", str(RUN), "--target", "dx_um", "--seed", str(2**32)])
    assert "argument --seed" in err


@pytest.mark.parametrize("hours", ["1e9", "721", "-1", "nan", "inf"])
def test_simulate_hours_beyond_a_month_are_refused(capsys, tmp_path, hours):
    err = _parse_error(capsys, ["simulate", "--hours", hours, "-o", str(tmp_path / "r.csv")])
    assert "argument --hours" in err and "between 0 and 720 h" in err
    assert not (tmp_path / "r.csv").exists()


def test_simulate_too_many_samples_is_refused(capsys, tmp_path):
    # 720 h at 0.1 s: 2.6e7 samples, beyond the 1e7 the simulator takes
    err = _error(capsys, ["simulate", "--hours", "700", "--cool-hours", "20", "--dt", "0.1",
                          "-o", str(tmp_path / "r.csv")])
    assert "2.59e+07 samples" in err and "more than 10,000,000" in err


def test_the_same_run_twice_is_refused(capsys):
    err = _error(capsys, ["train", str(RUN), str(RUN), "--target", "dx_um", "--no-codegen"])
    assert f"{RUN} is the same file as {RUN}" in err


def test_the_same_run_under_another_name_is_refused(capsys, tmp_path):
    copy_ = tmp_path / "copy.csv"
    shutil.copyfile(RUN, copy_)
    err = _error(capsys, ["train", str(OTHER), str(RUN), str(copy_), "--target", "dx_um",
                          "--no-codegen"])
    assert f"{copy_} has the same content as {RUN}" in err


def test_a_temperature_column_as_target_is_refused(capsys):
    err = _error(capsys, ["train", str(RUN), "--target", "T01", "--no-codegen"])
    assert "--target T01: that is a temperature column (it matches --sensors 'T*')" in err


def test_a_target_without_a_unit_suffix_is_refused(capsys):
    err = _error(capsys, ["train", str(RUN), "--target", "spindle_rpm", "--no-codegen"])
    assert "--target spindle_rpm" in err and "_um" in err and "_urad" in err


def test_constant_target_prints_no_nan_percent(capsys, tmp_path, model):
    """A constant displacement column (no drift measured): the reduction is undefined."""
    rows = list(csv.reader((EX / "sim_random.csv").open(encoding="utf-8")))
    i = rows[0].index("dx_um")
    for r in rows[1:]:
        r[i] = "0"
    run = tmp_path / "flat.csv"
    with run.open("w", newline="", encoding="utf-8") as fh:
        csv.writer(fh).writerows(rows)
    path = tmp_path / "m.json"
    path.write_text(json.dumps(model), encoding="utf-8")
    assert main(["evaluate", str(path), str(run)]) == 0
    out = capsys.readouterr().out
    assert "nan" not in out.lower()
    assert "dx_um: no drift measured" in out
    assert main(["evaluate", str(path), str(run), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["axes"]["dx_um"]["reduction_pct"] is None
    assert doc["axes"]["dx_um"]["raw_rms_um"] == 0.0


def test_a_1e300_time_is_out_of_range_not_milliseconds(tmp_path):
    rows = list(csv.reader(RUN.open(encoding="utf-8")))
    t = rows[0].index("time_s")
    rows[-1][t] = "1e300"  # the last sample: time still increases
    path = tmp_path / "r.csv"
    with path.open("w", newline="", encoding="utf-8") as fh:
        csv.writer(fh).writerows(rows)
    with pytest.raises(RunFormatError) as exc:
        load_run(path, targets=["dx_um"])
    msg = str(exc.value)
    assert isinstance(exc.value, InputError)
    assert f"{path}, line {len(rows)}, column 'time_s': time_s 1e+300 is out of range" in msg
    assert "milliseconds" in msg and "looks like milliseconds" not in msg


def test_real_milliseconds_are_still_called_milliseconds(tmp_path):
    rows = list(csv.reader(RUN.open(encoding="utf-8")))
    t = rows[0].index("time_s")
    for r in rows[1:]:
        r[t] = repr(float(r[t]) * 1000)
    path = tmp_path / "ms.csv"
    with path.open("w", newline="", encoding="utf-8") as fh:
        csv.writer(fh).writerows(rows)
    with pytest.raises(RunFormatError, match="looks like milliseconds"):
        load_run(path, targets=["dx_um"])

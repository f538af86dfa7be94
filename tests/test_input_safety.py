"""Issue 14 (host) and issue 15 (data-logger formats): every bad input gets a clear refusal
naming the file, line and column (or the model key), one regression test per input.

The models here are written by hand (two channels, one axis, a temp and a lag term) so each
expectation follows from the input crafted, not from what the code happened to print.
"""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest

from contract.box import BOX_CHANNELS
from contract.errors import InputError
from contract.model_file import (
    ModelFormatError,
    ModelHashError,
    check_model,
    model_hash,
    read_model,
    write_model,
)
from contract.terms import make_lag
from host.cli import main

N = 120  # samples of the hand-made run (1 s period)


def _model() -> dict:
    lag = make_lag("T02", 600.0, 1.0).to_json() | {"coef": -0.5}
    return {
        "schema": "thermal-model/1", "tool_version": "0.1.0", "sample_period_s": 1.0,
        "channels": [
            {"channel": 0, "sensor": "T01", "tc_type": "K", "min_c": -40.0, "max_c": 200.0,
             "trained_min_c": 20.0, "trained_max_c": 30.0},
            {"channel": 1, "sensor": "T02", "tc_type": "K", "min_c": -40.0, "max_c": 200.0,
             "trained_min_c": 20.0, "trained_max_c": 30.0}],
        "aux": [{"input": 0, "name": "spindle_rpm", "min": 0.0, "max": 12000.0}],
        "axes": {"dz_um": {"unit": "um", "intercept": 1.25,
                           "terms": [{"kind": "temp", "source": "T01", "coef": 2.0}, lag]}},
        "training": {"runs": ["run.csv"], "targets": ["dz_um"], "sensors": "T*",
                     "aux": ["spindle_rpm"]},
    }


def _run_text() -> str:
    t = np.arange(N, dtype=float)
    rows = ["time_s,T01,T02,spindle_rpm,dz_um"]
    for k in t:
        t1, t2 = 20 + 10 * k / N, 21 + 5 * k / N
        rows.append(f"{k:g},{t1:.4f},{t2:.4f},{1000 * (k > 30):g},{2 * t1 - 0.5 * t2:.4f}")
    return "\n".join(rows) + "\n"


@pytest.fixture
def files(tmp_path: Path) -> tuple[Path, Path]:
    model = tmp_path / "model.json"
    write_model(_model(), model)
    run = tmp_path / "run.csv"
    run.write_text(_run_text())
    return model, run


def _host(argv: list[str], capsys) -> tuple[int, str]:
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.err + out.out


# ---- the stored hash ------------------------------------------------------------------------

def test_write_model_stamps_the_hash_of_the_content(files):
    model, _ = files
    doc = json.loads(model.read_text())
    assert doc["model_hash"] == model_hash(_model())  # the function of the model, as written


def test_one_coefficient_digit_changed_is_refused_by_codegen_and_evaluate(files, capsys):
    model, run = files
    text = model.read_text()
    assert text.count('"coef": 2.0') == 1
    model.write_text(text.replace('"coef": 2.0', '"coef": 3.0'))  # still valid JSON
    header = model.with_name("model.h")
    code, err = _host(["codegen", model, "-o", header], capsys)
    assert code == 2 and not header.exists()
    stored, actual = model_hash(_model()), model_hash(json.loads(model.read_text()))
    assert f"{model}: model_hash" in err and stored in err and actual in err
    code, err = _host(["evaluate", model, run], capsys)
    assert code == 2 and "does not match the model's content" in err
    code, _ = _host(["evaluate", files[0].with_name("x.json"), run], capsys)
    assert code == 2


def test_a_fixed_point_block_of_another_model_is_refused(files):
    model, _ = files
    doc = json.loads(model.read_text())
    doc.pop("model_hash")
    doc["fixed_point"] = {"model_hash": "0123456789abcdef"}
    model.write_text(json.dumps(doc))
    with pytest.raises(ModelHashError, match=r"fixed_point\.model_hash.*'0123456789abcdef'"):
        read_model(model)
    with pytest.raises(ModelHashError):
        write_model(doc, model.with_name("again.json"))


def test_the_unedited_model_passes_every_reader(files, capsys):
    """The control for the refusals below: the same files are accepted."""
    model, run = files
    code, out = _host(["evaluate", model, run, "--json"], capsys)
    assert code == 0, out
    code, out = _host(["codegen", model, "-o", model.with_name("model.h")], capsys)
    assert code == 0, out


# ---- one validator for every command ----------------------------------------------------------

def _edit(fn) -> dict:
    m = copy.deepcopy(_model())
    fn(m)
    return m


def _terms(m: dict) -> list[dict]:
    return m["axes"]["dz_um"]["terms"]


BAD_MODELS = [
    ("nan coef", _edit(lambda m: _terms(m)[0].update(coef=float("nan"))),
     ["axis 'dz_um' term 0 temp(T01): coef", "finite", "nan"]),
    ("inf coef", _edit(lambda m: _terms(m)[0].update(coef=float("inf"))),
     ["axis 'dz_um' term 0 temp(T01): coef", "finite", "inf"]),
    ("1e30 coef", _edit(lambda m: _terms(m)[0].update(coef=1e30)),
     ["axis 'dz_um'", "temp(T01)", "1e+30", "int32"]),
    ("alpha -0.1", _edit(lambda m: _terms(m)[1].update(alpha=-0.1)),
     ["axis 'dz_um' term 1 lag(T02, tau=600s): alpha", "-0.1", "(0, 1]"]),
    ("alpha 2.0", _edit(lambda m: _terms(m)[1].update(alpha=2.0)),
     ["axis 'dz_um' term 1 lag(T02, tau=600s): alpha", "2.0", "(0, 1]"]),
    ("true coef", _edit(lambda m: _terms(m)[0].update(coef=True)),
     ["axis 'dz_um' term 0 temp(T01): coef", "expected a number", "True"]),
    ("channel min > max", _edit(lambda m: m["channels"][1].update(min_c=100.0, max_c=50.0)),
     ["channels[1] (T02)", "100..50", "empty"]),
    ("aux min > max", _edit(lambda m: m["aux"][0].update(min=5000.0, max=0.0)),
     ["aux[0] (spindle_rpm)", "5000..0", "empty"]),
    ("trained min > max", _edit(lambda m: m["channels"][0].update(trained_min_c=30.0,
                                                                  trained_max_c=20.0)),
     ["channels[0] (T01)", "training range 30..20 is empty"]),
    ("tc type", _edit(lambda m: m["channels"][0].update(tc_type="Q")),
     ["channels[0] (T01)", "thermocouple type 'Q'", "known: K, J"]),
    ("nine channels", _edit(lambda m: m["channels"].extend(
        {"channel": i, "sensor": f"T{i + 1:02d}", "tc_type": "K", "min_c": -40.0,
         "max_c": 200.0} for i in range(2, 9))),
     ["channels: 9 channels", f"the box has {BOX_CHANNELS}", "BOX_MAX_CHANNELS"]),
    ("bool index", _edit(lambda m: m["channels"][0].update(channel=False)),
     ["channels[0].channel", "integer index", "False"]),
    ("name", _edit(lambda m: m["axes"].update({"dz um": m["axes"].pop("dz_um")})),
     ["axes.dz um", "'dz um'", "1-32 characters"]),
]


@pytest.mark.parametrize("label, bad, fragments", BAD_MODELS, ids=[b[0] for b in BAD_MODELS])
def test_check_model_names_the_key(label, bad, fragments):
    check_model(_model())  # the unedited model is fine
    with pytest.raises(ModelFormatError) as err:
        check_model(bad, "m.json")
    for frag in fragments:
        assert frag in str(err.value), f"{label}: {frag!r} not in {err.value}"


@pytest.mark.parametrize("label, bad, fragments", BAD_MODELS, ids=[b[0] for b in BAD_MODELS])
@pytest.mark.parametrize("command", ["evaluate", "codegen", "diagnose", "report", "monitor"])
def test_every_command_refuses_what_codegen_refuses(files, capsys, command, label, bad,
                                                    fragments):
    good, run = files
    path = good.with_name("bad.json")
    path.write_text(json.dumps(bad))  # NaN/Infinity literals included, as a hand edit would
    argv = {"evaluate": ["evaluate", path, run], "codegen": ["codegen", path],
            "diagnose": ["diagnose", path, run],
            "report": ["report", path, "--runs", run, "-o", good.with_name("rep")],
            "monitor": ["monitor", "/dev/null/not-a-port", "--model", path, "--count", "1"],
            }[command]
    code, err = _host(argv, capsys)
    assert code == 2, err
    assert str(path) in err and fragments[0] in err, err


def test_hil_replay_goes_through_the_same_validator(files, capsys):
    from hil.cli import main as hil_main

    good, run = files
    path = good.with_name("bad.json")
    path.write_text(json.dumps(BAD_MODELS[3][1]))
    assert hil_main(["replay", "--model", str(path), "--data", str(run)]) == 2
    assert "alpha" in capsys.readouterr().err


def test_codegen_errors_are_input_errors():
    import codegen

    with pytest.raises(codegen.CodegenError, match="term 1 lag") as err:
        codegen.generate(BAD_MODELS[3][1])
    assert isinstance(err.value, InputError)


# ---- argument validation ------------------------------------------------------------------

@pytest.mark.parametrize("command", ["train", "evaluate", "diagnose", "report", "compare"])
def test_negative_fill_gaps_is_refused_by_argparse(files, capsys, command):
    model, run = files
    argv = {"train": ["train", run, "--target", "dz_um"],
            "evaluate": ["evaluate", model, run], "diagnose": ["diagnose", model, run],
            "report": ["report", model, "--runs", run],
            "compare": ["compare", run, "--test", run, "--target", "dz_um"]}[command]
    with pytest.raises(SystemExit) as exc:
        main([str(a) for a in argv] + ["--fill-gaps", "-3"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "argument --fill-gaps" in err and "-3" in err

"""Issue 14 (host) and issue 15 (data-logger formats): every bad input gets a clear refusal
naming the file, line and column (or the model key), one regression test per input.

The models here are written by hand (two channels, one axis, a temp and a lag term) so each
expectation follows from the input crafted, not from what the code happened to print.
"""

from __future__ import annotations

import copy
import json
import re
from pathlib import Path

import numpy as np
import pytest

from thermal_comp.contract.box import BOX_CHANNELS
from thermal_comp.contract.errors import InputError
from thermal_comp.contract.model_file import (
    ModelFormatError,
    ModelHashError,
    check_model,
    model_hash,
    read_model,
    write_model,
)
from thermal_comp.contract.terms import make_lag
from thermal_comp.host.cli import main

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


def test_a_changed_reference_is_a_changed_model(files):
    """start vs none decides whether the box zeroes at power-up: part of the hash."""
    model, _ = files
    doc = json.loads(model.read_text())
    doc.pop("model_hash")
    doc["reference"] = {"kind": "start", "samples": 8}
    write_model(doc, model)
    model.write_text(model.read_text().replace('"kind": "start"', '"kind": "none"'))
    with pytest.raises(ModelHashError, match="model_hash"):
        read_model(model)


def test_codegen_says_when_a_model_has_no_hash_to_check(files, capsys):
    model, _ = files
    doc = json.loads(model.read_text())
    code, err = _host(["codegen", model, "-o", model.with_name("a.h")], capsys)
    assert code == 0 and "no model_hash" not in err
    doc.pop("model_hash")
    model.write_text(json.dumps(doc))
    code, err = _host(["codegen", model, "-o", model.with_name("b.h")], capsys)
    assert code == 0 and f"note: {model} carries no model_hash" in err


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
    ("reference kind", _edit(lambda m: m.update(reference={"kind": "Start", "samples": 8})),
     ["reference.kind", "'Start'", "start, none"]),
    ("reference samples", _edit(lambda m: m.update(reference={"kind": "start", "samples": "8"})),
     ["reference.samples", "'8'"]),
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
    from thermal_comp.hil.cli import main as hil_main

    good, run = files
    path = good.with_name("bad.json")
    path.write_text(json.dumps(BAD_MODELS[3][1]))
    assert hil_main(["replay", "--model", str(path), "--data", str(run)]) == 2
    assert "alpha" in capsys.readouterr().err


def test_codegen_errors_are_input_errors():
    from thermal_comp import codegen

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


# ---- run files: impossible values -------------------------------------------------------------

def _rows(text: str) -> list[list[str]]:
    return [line.split(",") for line in text.splitlines()]


def _with_cell(text: str, line: int, column: str, value: str) -> str:
    rows = _rows(text)
    rows[line - 1][rows[0].index(column)] = value
    return "\n".join(",".join(r) for r in rows) + "\n"


def _load(path: Path, **kw):
    from thermal_comp.host.io import load_run

    return load_run(path, ["dz_um"], "T*", ["spindle_rpm"], **kw)


def _refusal(path: Path, **kw) -> str:
    with pytest.raises(InputError) as err:  # RunFormatError, or EncodingError
        _load(path, **kw)
    return str(err.value)


def test_a_temperature_of_1e9_is_refused_naming_file_line_and_column(tmp_path, capsys):
    p = tmp_path / "hot.csv"
    p.write_text(_with_cell(_run_text(), 40, "T02", "1e9"))
    msg = _refusal(p)
    assert f"{p}, line 40, column 'T02': 1e+09 degC" in msg and "-40..200 degC" in msg
    code, err = _host(["train", p, "--target", "dz_um", "--no-codegen", "--out", tmp_path],
                      capsys)
    assert code == 2 and "line 40, column 'T02'" in err
    assert not (tmp_path / "model.json").exists()


def test_a_temperature_outside_the_models_channel_range_is_refused_by_evaluate(files, capsys):
    model, run = files
    doc = json.loads(model.read_text())
    doc["channels"][0]["max_c"] = 25.0  # T01 = 20 + 10 k / 120 passes 25 at k = 61, line 63
    doc.pop("model_hash")
    model.write_text(json.dumps(doc))
    code, err = _host(["evaluate", model, run], capsys)
    assert code == 2 and "line 63, column 'T01'" in err and "-40..25 degC" in err


def test_a_kelvin_column_is_named_as_such(tmp_path):
    rows = _rows(_run_text())
    i = rows[0].index("T01")
    for r in rows[1:]:
        r[i] = f"{float(r[i]) + 273.15:.2f}"
    p = tmp_path / "kelvin.csv"
    p.write_text("\n".join(",".join(r) for r in rows) + "\n")
    msg = _refusal(p)
    assert "line 2, column 'T01': 293.15 degC" in msg and "looks like kelvin" in msg


@pytest.mark.parametrize("column, words", [
    ("T01", "1e+308 degC is outside the thermocouple channel's valid range"),
    ("dz_um", "1e+308 um is beyond any correction the box can output"),
    ("spindle_rpm", "1e+308 is beyond the box's int32 auxiliary input"),
])
def test_a_1e308_cell_is_refused_where_it_is(tmp_path, column, words):
    p = tmp_path / "big.csv"
    p.write_text(_with_cell(_run_text(), 7, column, "1e308"))
    msg = _refusal(p)
    assert f"line 7, column '{column}'" in msg and words in msg


# ---- run files: time ----------------------------------------------------------------------------

def _with_time(text: str, fn) -> str:
    rows = _rows(text)
    for k, r in enumerate(rows[1:]):
        r[0] = f"{fn(k, float(r[0])):g}"
    return "\n".join(",".join(r) for r in rows) + "\n"


def test_a_one_hour_gap_is_refused_naming_it_and_where_to_cut(tmp_path):
    p = tmp_path / "gap.csv"
    p.write_text(_with_time(_run_text(), lambda k, t: t + 3600 * (k >= 50)))
    msg = _refusal(p)
    # rows k = 49 (t 49 s, line 51) and k = 50 (t 3650 s, line 52)
    assert f"{p}, line 52, column 'time_s'" in msg
    assert "jumps from 49 to 3650 s: a gap of 3601 s" in msg and "filters" in msg
    assert f"host split {p} --at-hours {3650 / 3600:.6g}" in msg


def test_host_split_cuts_at_the_gap_and_both_parts_load(tmp_path, capsys):
    p = tmp_path / "gap.csv"
    p.write_text(_with_time(_run_text(), lambda k, t: t + 3600 * (k >= 50)))
    code, out = _host(["split", p, "--at-hours", str(3650 / 3600), "-o", tmp_path, "--json"],
                      capsys)
    assert code == 0, out
    parts = [Path(x) for x in json.loads(out)["parts"]]
    assert [_load(x).n_samples for x in parts] == [50, N - 50]


def test_a_few_missing_rows_are_filled_with_fill_gaps(tmp_path):
    p = tmp_path / "missing.csv"
    lines = _run_text().splitlines()
    p.write_text("\n".join(lines[:31] + lines[33:]) + "\n")  # rows t = 30, 31 s dropped
    assert "about 2 missing samples" in _refusal(p)
    assert "--fill-gaps 2" in _refusal(p)
    run = _load(p, fill_gaps=2)
    full = _load(_write(tmp_path / "full.csv", _run_text()))
    np.testing.assert_array_equal(run.time_s, full.time_s)
    np.testing.assert_allclose(run.temperatures, full.temperatures, atol=1e-3)  # linear data
    assert run.filled_cells == 2 * 4  # two rows of T01, T02, dz_um, spindle_rpm


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_jitter_of_7_s_is_named_with_the_period_it_implies(tmp_path):
    p = tmp_path / "jitter.csv"
    # a 60 s grid, samples 7 s late or early in turn: steps 67, 46, 67, 67, 46, ... whose
    # median is 67 s (what the period became before)
    p.write_text(_with_time(_run_text(), lambda k, t: 60 * k + 7 * ((k % 3 == 1) - (k % 3 == 2))))
    msg = _refusal(p)
    assert "line 3, column 'time_s'" in msg  # k = 1: 0 -> 67 s
    assert re.search(r"deviate up to ±7(\.\d)? s from a regular grid of 60 s", msg), msg
    assert "steps from 46 to 67 s" in msg and "resample the run to 60 s" in msg


@pytest.mark.parametrize("step_ms, seconds", [(60_000, 60), (1000, 1), (250, 0.25)])
def test_time_in_milliseconds_is_named(tmp_path, step_ms, seconds):
    p = tmp_path / "ms.csv"
    n = N if step_ms >= 1000 else 6000  # 250 ms for 25 min: 17 "days" in seconds
    rows = _run_text().splitlines()
    rows = rows[:1] + [rows[1 + k % N] for k in range(n)]
    p.write_text(_with_time("\n".join(rows) + "\n", lambda k, t: step_ms * k))
    msg = _refusal(p)
    assert "time_s looks like milliseconds" in msg and f"a step of {seconds:g} s" in msg


def test_a_five_minute_run_in_seconds_is_not_mistaken_for_milliseconds(tmp_path):
    p = tmp_path / "slow.csv"
    p.write_text(_with_time(_run_text(), lambda k, t: 300 * k))  # 10 h at 5 min
    assert _load(p).period_s == 300


# ---- run files: nothing to learn -------------------------------------------------------------

def test_a_constant_target_is_refused_by_train(tmp_path, capsys):
    rows = _rows(_run_text())
    for r in rows[1:]:
        r[rows[0].index("dz_um")] = "0"
    p = _write(tmp_path / "flat.csv", "\n".join(",".join(r) for r in rows) + "\n")
    code, err = _host(["train", p, "--target", "dz_um", "--no-codegen", "--out", tmp_path],
                      capsys)
    assert code == 2 and "target 'dz_um' is constant in every training run" in err
    assert "column 'dz_um'" in err


def test_all_sensors_constant_is_refused_by_train(tmp_path, capsys):
    rows = _rows(_run_text())
    for r in rows[1:]:
        r[1], r[2] = "21.5", "22.0"
    p = _write(tmp_path / "cold.csv", "\n".join(",".join(r) for r in rows) + "\n")
    code, err = _host(["train", p, "--target", "dz_um", "--no-codegen", "--out", tmp_path],
                      capsys)
    assert code == 2 and "every sensor (T01, T02) is constant" in err


# ---- run and model files: encodings and delimiters --------------------------------------------

def test_a_latin1_csv_names_file_line_and_byte(tmp_path):
    p = tmp_path / "latin1.csv"
    lines = _run_text().splitlines()
    lines[4] = lines[4] + ",Temp\xe9rature"  # line 5, a stray Latin-1 e-acute
    p.write_bytes("\n".join(lines).encode("latin-1"))
    msg = _refusal(p)
    col = len(lines[4]) - len("rature")  # 1-based character of the bad byte
    assert f"{p}, line 5, character {col}: byte 0xE9 is not valid UTF-8" in msg
    assert "'é'" in msg


def test_a_utf16_csv_is_named_from_its_byte_order_mark(tmp_path):
    p = tmp_path / "unicode.csv"
    p.write_bytes(_run_text().encode("utf-16"))  # with BOM, as Excel's "Unicode text"
    msg = _refusal(p)
    assert f"{p}, line 1: the file is UTF-16 LE (byte-order mark FF FE)" in msg


@pytest.mark.parametrize("encoding, words", [("utf-16", "UTF-16 LE (byte-order mark FF FE)"),
                                             ("latin-1", "byte 0xB0 is not valid UTF-8")])
def test_a_model_json_in_another_encoding_is_named(files, capsys, encoding, words):
    model, run = files
    doc = json.loads(model.read_text())
    doc["training"]["note"] = "max 30\xb0C"  # a degree sign in a free-text field
    model.write_bytes(json.dumps(doc, ensure_ascii=False).encode(encoding))
    for argv in (["evaluate", model, run], ["codegen", model]):
        code, err = _host(argv, capsys)
        assert code == 2 and str(model) in err and words in err, err


def _logger_text() -> str:
    """The run of _run_text as a European data logger writes it: ';', decimal commas and ISO
    timestamps (one sample per second from 2024-03-01 08:00:00)."""
    rows = _rows(_run_text())
    out = ["timestamp;T01;T02;spindle_rpm;dz_um"]
    for r in rows[1:]:
        k = int(float(r[0]))
        stamp = f"2024-03-01 08:{k // 60:02d}:{k % 60:02d}"
        out.append(";".join([stamp] + [c.replace(".", ",") for c in r[1:]]))
    return "\n".join(out) + "\n"


def test_a_data_logger_file_reads_as_the_plain_csv(tmp_path):
    plain = _load(_write(tmp_path / "plain.csv", _run_text()))
    logger = _load(_write(tmp_path / "logger.csv", _logger_text()))
    np.testing.assert_array_equal(logger.time_s, plain.time_s)
    np.testing.assert_array_equal(logger.temperatures, plain.temperatures)
    np.testing.assert_array_equal(logger.displacements, plain.displacements)


def test_a_semicolon_file_read_with_a_comma_separator_names_the_delimiter(tmp_path):
    from thermal_comp.host.io import CsvFormat

    p = _write(tmp_path / "semi.csv", _logger_text())
    msg = _refusal(p, fmt=CsvFormat(sep=","))
    assert f"{p}, line 1:" in msg and "semicolon (';')-delimited" in msg and "--sep ';'" in msg


def test_format_errors_keep_file_line_and_column(tmp_path):
    text = _logger_text().splitlines()
    text[9] = text[9].replace(";2", ";2x", 1)  # line 10, the T01 cell
    text[20] = "2024-03-01 08:00:19.5;" + text[20].split(";", 1)[1]  # fine: a timestamp
    p = _write(tmp_path / "bad.csv", "\n".join(text) + "\n")
    msg = _refusal(p)
    assert "line 10, column 'T01': not a number" in msg
    text[9] = text[9].replace(";2x", ";2", 1)
    text[30] = "32.03.2024 08:00:29;" + text[30].split(";", 1)[1]  # day-first, no such day
    p.write_text("\n".join(text) + "\n")
    msg = _refusal(p)
    assert "line 31, column 'timestamp'" in msg and "nor a timestamp" in msg
    assert "01.03.2024 12:00:00" in msg  # the day-first form it would read (issue 43)


def test_time_col_names_the_time_column(tmp_path):
    from thermal_comp.host.io import CsvFormat

    text = _logger_text().replace("timestamp;", "Zeitstempel;", 1)
    p = _write(tmp_path / "named.csv", text)
    sniffed = _load(p)  # the only column of timestamps
    given = _load(p, fmt=CsvFormat(time_col="Zeitstempel"))
    np.testing.assert_array_equal(sniffed.time_s, np.arange(N, dtype=float))
    np.testing.assert_array_equal(given.time_s, sniffed.time_s)
    assert "missing time column (given by --time-col)" in _refusal(p, fmt=CsvFormat(
        time_col="stamp"))


def test_every_command_that_reads_runs_reads_a_data_logger_file(files, tmp_path, capsys):
    model, run = files
    logger = _write(tmp_path / "logger.csv", _logger_text())
    fmt = ["--sep", ";", "--decimal", ",", "--time-col", "timestamp"]
    for extra in ([], fmt):
        code, out = _host(["evaluate", model, logger, "--json", *extra], capsys)
        assert code == 0, out
        plain_code, plain = _host(["evaluate", model, run, "--json"], capsys)
        assert json.loads(out)["axes"] == json.loads(plain)["axes"]
        code, out = _host(["diagnose", model, logger, "--json", *extra], capsys)
        assert code == 0, out
        code, out = _host(["split", logger, "--at-hours", str(60 / 3600), "-o",
                           tmp_path / "parts", "--json", *extra], capsys)
        assert code == 0, out
        first = Path(json.loads(out)["parts"][0])
        assert first.read_text().startswith("time_s,T01,T02,spindle_rpm,dz_um\n0,20,21,0,")
    code, out = _host(["train", logger, "--target", "dz_um", "--no-codegen", "--no-effects",
                       "--out", tmp_path / "m", "--json", *fmt], capsys)
    assert code == 0, out
    code, out = _host(["compare", logger, "--test", logger, "--target", "dz_um",
                       "--exhaustive-limit", "0", "--json", *fmt], capsys)
    assert code == 0, out
    code, out = _host(["report", model, "--runs", logger, "--no-peers", "-o", tmp_path / "r",
                       "--json", *fmt], capsys)
    assert code == 0, out


def test_clashing_format_options_are_refused(files, capsys):
    model, run = files
    code, err = _host(["evaluate", model, run, "--sep", ",", "--decimal", ","], capsys)
    assert code == 2 and "--decimal ',' needs a --sep other than ','" in err

"""The run loader rejects every kind of bad input with file, line and column in the message."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from thermal_comp.host.io import RunFormatError, load_run, load_runs, write_run

GOOD = "time_s,T01,T02,spindle_rpm,dz_um\n0,20,21,0,0.0\n1,20.5,21,100,0.5\n2,21,21.5,100,1.0\n"


def write(tmp_path: Path, text: str, name: str = "run.csv") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def test_good_run_splits_columns_by_role(tmp_path):
    run = load_run(write(tmp_path, GOOD), ["dz_um"], "T*", ["spindle_rpm"])
    assert run.sensor_names == ["T01", "T02"]
    np.testing.assert_array_equal(run.temperatures[:, 1], [21, 21, 21.5])
    np.testing.assert_array_equal(run.target("dz_um"), [0, 0.5, 1.0])
    np.testing.assert_array_equal(run.aux[:, 0], [0, 100, 100])
    assert run.period_s == 1.0


@pytest.mark.parametrize("text, line, column, words", [
    ("T01,dz_um\n20,0\n21,1\n", 1, "time_s", "missing column"),
    ("time_s,T01,T01,dz_um\n0,1,1,0\n1,1,1,0\n", 1, "T01", "duplicate"),
    ("time_s,T01\n0,1\n1,2\n", 1, "dz_um", "missing target"),
    ("time_s,T01,dz_um\n0,20,0\n1,abc,0\n", 3, "T01", "not a number"),
    ("time_s,T01,dz_um\n0,20,0\n1,,0\n2,20,0\n", 3, "T01", "empty or NaN"),
    ("time_s,T01,dz_um\n0,20,0\n1,nan,0\n2,20,0\n", 3, "T01", "empty or NaN"),
    ("time_s,T01,dz_um\n0,20,0\n2,20,0\n2,20,0\n", 4, "time_s", "does not increase"),
    ("time_s,T01,dz_um\n0,20,0\n2,20,0\n1,20,0\n", 4, "time_s", "does not increase"),
])
def test_rejections_name_file_line_and_column(tmp_path, text, line, column, words):
    p = write(tmp_path, text)
    with pytest.raises(RunFormatError) as err:
        load_run(p, ["dz_um"])
    msg = str(err.value)
    assert str(p) in msg and f"line {line}" in msg and f"column '{column}'" in msg
    assert words in msg


def test_ragged_row_names_its_line(tmp_path):
    p = write(tmp_path, "time_s,T01,dz_um\n0,20,0\n1,20\n")
    with pytest.raises(RunFormatError, match=r"line 3: 2 cells"):
        load_run(p, ["dz_um"])


def test_too_few_samples_is_rejected(tmp_path):
    with pytest.raises(RunFormatError, match="3 samples, the model needs at least 10"):
        load_run(write(tmp_path, GOOD), ["dz_um"], min_samples=10)


def test_no_sensor_matches_glob(tmp_path):
    with pytest.raises(RunFormatError, match="no temperature column matches"):
        load_run(write(tmp_path, GOOD), ["dz_um"], sensors="X*")


def test_fill_gaps_interpolates_short_gaps_and_counts_them(tmp_path):
    text = "time_s,T01,dz_um\n0,20,0\n1,,0\n2,,0\n3,23,0\n4,24,0\n"
    run = load_run(write(tmp_path, text), ["dz_um"], fill_gaps=2)
    np.testing.assert_allclose(run.temperatures[:, 0], [20, 21, 22, 23, 24])
    assert run.filled_cells == 2
    with pytest.raises(RunFormatError, match=r"line 3, column 'T01': gap of 2 .* --fill-gaps 1"):
        load_run(write(tmp_path, text), ["dz_um"], fill_gaps=1)


def test_runs_with_different_sensors_are_rejected(tmp_path):
    a = write(tmp_path, GOOD, "a.csv")
    b = write(tmp_path, GOOD.replace("T02", "T03"), "b.csv")
    with pytest.raises(RunFormatError, match="sensor columns differ"):
        load_runs([a, b], ["dz_um"])


def test_write_run_round_trips(tmp_path):
    t = np.arange(5.0)
    cols = {"T01": 20 + t / 3, "dz_um": t * 0.25}
    write_run(tmp_path / "x.csv", t, cols, precision=10)
    run = load_run(tmp_path / "x.csv", ["dz_um"])
    np.testing.assert_allclose(run.temperatures[:, 0], cols["T01"], rtol=1e-9)
    np.testing.assert_allclose(run.target("dz_um"), cols["dz_um"])

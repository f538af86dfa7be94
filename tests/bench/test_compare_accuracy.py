"""Two accuracy benches compared (bench/compare_accuracy.py): the paired ratios per source, the
counts beyond 5 %, the interval over whole training sets, the cases only one bench holds, and
a clear error for a file that is not a bench's JSON."""

import json
import math
from dataclasses import asdict

import pytest

from bench import bench_accuracy as acc
from bench import compare_accuracy as cmp


def bench_doc(errors: dict[tuple[str, str, str], float], peer: float = 1.0) -> dict:
    """A bench JSON of cases keyed (source, training set, test run), dy only."""
    cases = []
    for (source, unit, test), ours in errors.items():
        c = acc.CaseResult(source, f"{unit} one variant", test, "dy_um", "start", unit)
        c.rmse_um = {"default": ours, "no effects": 2 * ours, "OLS all": peer}
        cases.append(asdict(c))
    return {"cases": cases, "summary": {}}


def write(tmp_path, name: str, doc: dict):
    p = tmp_path / name
    p.write_text(json.dumps(doc))
    return p


def test_paired_ratio_counts_and_interval(tmp_path):
    before = {("sim_dev", u, t): 1.0 for u in "ABCD" for t in ("t1", "t2")}
    before |= {("fl", u, "held"): 2.0 for u in "AB"}
    after = dict(before)
    after[("sim_dev", "A", "t1")] = 0.25  # one case 4x better, one 4x worse in another set
    after[("sim_dev", "B", "t2")] = 4.0
    after[("sim_dev", "C", "t1")] = 1.04  # inside the 5 % either way
    after = {k: v / 2 if k[0] == "fl" else v for k, v in after.items()}
    after[("sim", "X", "only after")] = 1.0
    b = cmp.load(write(tmp_path, "b.json", bench_doc(before)))
    a = cmp.load(write(tmp_path, "a.json", bench_doc(after)))
    moved = {m.source: m for m in cmp.compare(b, a)}
    assert set(moved) == {"sim_dev", "fl"}  # the case only one bench holds is left out
    dev = moved["sim_dev"]
    assert (dev.cases, dev.training_sets, dev.worse, dev.better) == (8, 4, 1, 1)
    assert dev.geomean == pytest.approx(1.04 ** (1 / 8))
    lo, hi = dev.interval
    # a draw of sets A only is 0.5, of B only 2: the interval lies between and holds 1
    assert 0.5 <= lo < 1 < hi <= 2
    fl = moved["fl"]
    assert (fl.geomean, fl.worse, fl.better) == (pytest.approx(0.5), 0, 2)
    assert all(math.isnan(x) for x in fl.interval)  # two training sets: no interval
    assert (fl.target_before, fl.target_after) == (pytest.approx(2.0), pytest.approx(1.0))
    # one bench against itself: its loop, no effects -> default, halves every case
    loop = {m.source: m for m in cmp.compare(a, a, "default", "no effects")}
    assert loop["sim_dev"].geomean == pytest.approx(0.5)
    assert loop["sim_dev"].interval == pytest.approx((0.5, 0.5))
    assert "none (< 3)" in cmp.table(list(moved.values()), "default", None)


def test_command_line_prints_the_table_and_draws_the_cases(tmp_path, capsys):
    doc = bench_doc({("sim_dev", u, "t"): 1.0 for u in "ABC"})
    p = write(tmp_path, "x.json", doc)
    out = tmp_path / "cmp.png"
    assert cmp.main([str(p), str(p), "--against", "no effects", "--plot", str(out)]) == 0
    text = capsys.readouterr().out
    assert "sim_dev" in text and "0.500" in text
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_file_that_is_not_a_bench_names_itself(tmp_path):
    bad = write(tmp_path, "notes.json", {"rows": []})
    with pytest.raises(SystemExit, match="notes.json: not an accuracy bench"):
        cmp.load(bad)
    with pytest.raises(SystemExit, match="missing.json: no such file"):
        cmp.load(tmp_path / "missing.json")
    ok = write(tmp_path, "ok.json", bench_doc({("fl", "A", "t"): 1.0}))
    with pytest.raises(SystemExit):  # no column "paper" in either: nothing to compare
        cmp.main([str(ok), str(ok), "--column", "paper"])

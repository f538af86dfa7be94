"""The bench runner (``python -m bench [SUITE ...]``): suites, goals, the table, the merged JSON."""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

from bench.__main__ import format_row, merge, summary
from bench.goal import INFO, goal, verdict

ROOT = Path(__file__).resolve().parents[2]


def test_an_option_meant_for_a_suite_is_refused_with_where_it_goes():
    # `--source fl` belongs to `python -m bench.bench_accuracy`; the runner would have run the
    # whole accuracy bench (15 min) and ignored it
    done = subprocess.run([sys.executable, "-m", "bench", "accuracy", "--source", "fl"],
                          cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    assert "not a suite: --source fl" in done.stderr
    assert "python -m bench.bench_<suite> --help" in done.stderr
    assert "accuracy" in done.stderr and "train" in done.stderr  # the suites it knows
    assert done.stdout == ""


# --- goals, the table, the summary and the merged JSON (issue 46) ---------------------------

def _row(value, g, name="a row", suite="train", **kw):
    row = {"suite": suite, "name": name, "value": value, "unit": "s", "goal": g, **kw}
    row["result"] = verdict(row)
    return row


def test_a_goal_is_checked_an_info_row_is_not_counted_and_a_row_without_one_fails():
    assert verdict({"value": 9.9, "goal": goal("<=", 10)}) == "pass"
    assert verdict({"value": 10.1, "goal": goal("<=", 10)}) == "fail"
    assert verdict({"value": 10, "goal": goal("<", 10)}) == "fail"
    assert verdict({"value": 0, "goal": goal("==", 0)}) == "pass"
    assert verdict({"value": 0.79, "goal": goal(">=", 0.8)}) == "fail"
    assert verdict({"value": float("nan"), "goal": goal("<=", 1)}) == "fail"  # not measured
    assert verdict({"value": 123, "goal": INFO}) == "info"
    assert verdict({"value": 1, "target": "< 10 s"}) == "no goal"  # words alone are not a goal


def test_every_row_a_suite_builds_carries_a_goal():
    # every dict literal with a "name" and a "value" in bench/bench_*.py is a row: it must
    # say its goal (or INFO), else the runner counts it as failed at the end of a long run
    missing = []
    for path in sorted((ROOT / "bench").glob("bench_*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Dict):
                keys = {k.value for k in node.keys if isinstance(k, ast.Constant)}
                if {"name", "value"} <= keys and "goal" not in keys:
                    missing.append(f"{path.name}:{node.lineno}")
    assert missing == []


def test_long_names_wrap_in_their_own_column_and_the_result_column_stays_put():
    short = format_row(_row(1.5, goal("<=", 10), target="<= 10 s"), 8)
    long = format_row(_row(12.0, goal("<=", 10), name="host train (default: effects + codegen)"
                           ", 64 sensors x 86,400 rows and then some more words",
                           target="<= 10 s"), 8)
    assert len(short) == 1 and len(long) == 2
    assert short[0].index("pass") == long[0].index("FAIL")  # same column
    assert long[0].endswith("FAIL    <= 10 s")
    assert long[1].split()[-3:] == ["some", "more", "words"]  # the rest of the name
    assert long[1].strip().startswith("sensors") and long[1].index("sensors") == \
        long[0].index("host")
    info = format_row(_row(3, INFO), 8)[0]
    assert info.rstrip().endswith("info")


def test_the_summary_counts_pass_fail_info_and_names_the_failing_rows():
    rows = [_row(1, goal("<=", 10), name="fast"), _row(11, goal("<=", 10), name="slow"),
            _row(5, INFO, name="spread"), {**_row(1, None, name="new"), "result": "no goal"}]
    line = summary(rows)
    assert line.startswith("bench: 1 pass, 2 fail, 1 info (4 rows)")
    assert "failing: train: slow; train: new (no goal)" in line


def test_a_partial_run_replaces_its_suite_s_rows_and_keeps_the_others(tmp_path):
    path = tmp_path / "bench.json"
    path.write_text(json.dumps({"machine": "m", "python": "3", "rows": [
        _row(1, INFO, name="old train row", suite="train"),
        _row(0.7, goal("<=", 0.8), name="fl ratio", suite="accuracy")]}))
    merged = merge(path, {"train": {"when": "now", "commit": "abc"}},
                   [_row(8, goal("<=", 10), name="new train row", suite="train")])
    assert [r["name"] for r in merged["rows"]] == ["fl ratio", "new train row"]
    assert merged["suites"]["train"]["commit"] == "abc"
    assert merged["suites"]["accuracy"]["machine"] == "m"  # the kept rows keep their machine
    assert merge(tmp_path / "none.json", {"train": {}}, [])["rows"] == []  # no file yet

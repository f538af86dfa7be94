"""The bench runner (``python -m bench [SUITE ...]``): a name that is no suite is refused."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


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

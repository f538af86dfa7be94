"""A reader that stops early ends any `host` command quietly, as it ends a Unix tool."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _simulate(tmp_path: Path) -> list[str]:
    return [sys.executable, "-m", "thermal_comp.host", "simulate", "-o", str(tmp_path / "run.csv"),
            "--hours", "0.5", "--cool-hours", "0.5", "--json"]


def test_a_pipe_closed_before_the_output_ends_the_command_quietly(tmp_path):
    # the reader is gone before the command writes a byte (deterministic, unlike a race with
    # head): it used to print "host simulate: error: : Broken pipe" and exit 2
    proc = subprocess.Popen(_simulate(tmp_path), cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
    proc.stdout.close()
    err = proc.stderr.read()
    assert proc.wait(timeout=120) == 141  # 128 + SIGPIPE, as a shell reports `yes | head -1`
    assert err == b""


def test_a_shell_pipeline_into_head_leaves_stderr_empty(tmp_path):
    # head -n 0 exits at once, long before the interpreter has started: the write finds no
    # reader; `| head -1` races with the output (it often comes in one write before head exits)
    cmd = " ".join(_simulate(tmp_path))
    done = subprocess.run(["bash", "-c", f"{cmd} 2>{tmp_path / 'err'} | head -n 0; "
                           "echo ${PIPESTATUS[0]}"], cwd=ROOT, capture_output=True, text=True,
                          timeout=120)
    assert done.stdout.strip() == "141"
    assert (tmp_path / "err").read_text() == ""
    assert (tmp_path / "run.csv").exists()  # the command did its work


def test_a_reader_that_stays_gets_the_whole_output(tmp_path):
    done = subprocess.run([*_simulate(tmp_path)], cwd=ROOT, capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0 and done.stderr == ""
    assert done.stdout.lstrip().startswith("{")

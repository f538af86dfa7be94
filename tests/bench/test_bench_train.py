"""bench.bench_train's timing: fresh processes, the fastest reported, every run kept."""

from __future__ import annotations

import sys

import pytest

from bench.bench_train import Timing, timed_process


def test_the_fastest_of_the_runs_is_the_figure_and_every_run_is_shown():
    timing = Timing((7.31, 5.52, 6.04), 512.0)
    assert timing.fastest == 5.52
    assert timing.describe() == "fastest of 3 fresh processes (7.31, 5.52, 6.04 s)"


def test_each_run_is_a_fresh_process_with_its_own_peak_memory():
    # the child's own peak: neither this (larger) test process's, which Linux would carry
    # across fork + exec, nor the launcher's
    small = timed_process([sys.executable, "-c", "pass"], repeat=2)
    assert len(small.seconds) == 2 and all(s > 0 for s in small.seconds)
    assert small.peak_mb < 50
    grow = "b = bytearray(200 * 1024 * 1024); b[::4096] = b'x' * len(b[::4096])"
    assert timed_process([sys.executable, "-c", grow], repeat=1).peak_mb > 200


def test_a_failing_command_is_an_error_not_a_time():
    with pytest.raises(RuntimeError, match="failed"):
        timed_process([sys.executable, "-c", "raise SystemExit(3)"], repeat=1)


def test_memory_is_summed_over_every_process_the_command_starts():
    # three forked workers with 150 MB each of their own: the tree holds > 450 MB while no
    # single process ever passes ~170 MB (what the old measure, one child's ru_maxrss, saw)
    workers = ("import os, time\n"
               "pids = []\n"
               "for _ in range(3):\n"
               "    pid = os.fork()\n"
               "    if pid == 0:\n"
               "        b = bytearray(150 * 1024 * 1024); b[::4096] = b'x' * len(b[::4096])\n"
               "        time.sleep(1.0)\n"
               "        os._exit(0)\n"
               "    pids.append(pid)\n"
               "for pid in pids:\n"
               "    os.waitpid(pid, 0)\n")
    timing = timed_process([sys.executable, "-c", workers], repeat=1)
    assert timing.largest_mb < 200
    assert timing.peak_mb > 420
    assert timing.procs == 4
    assert "(4 at most at once)" in timing.describe_memory()

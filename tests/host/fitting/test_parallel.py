"""host.parallel: the items spread over forked processes, the results as the serial loop's."""

from __future__ import annotations

import os

import numpy as np
import pytest

from thermal_comp.host.parallel import forked_map, usable_cores


class TwoPartError(Exception):
    """An error whose constructor takes two arguments: pickling it back from a worker fails."""

    def __init__(self, where: str, what: str) -> None:
        super().__init__(f"{where}: {what}")


def test_forked_map_keeps_the_order_and_runs_in_other_processes():
    data = np.arange(50.0) ** 2  # inherited by the children, never pickled

    def work(i: int) -> tuple[int, float, int]:
        return i, float(data[i]), os.getpid()

    out = forked_map(work, range(50), "squares", workers=2)
    assert [(i, v) for i, v, _ in out] == [(i, float(i * i)) for i in range(50)]
    pids = {pid for _, _, pid in out}
    assert os.getpid() not in pids and 1 <= len(pids) <= 2


def test_one_worker_or_one_item_runs_in_this_process():
    assert forked_map(lambda i: os.getpid(), range(3), "here", workers=1) == [os.getpid()] * 3
    assert forked_map(lambda i: os.getpid(), [7], "here", workers=4) == [os.getpid()]
    assert forked_map(lambda i: i, [], "nothing", workers=4) == []


def test_an_error_in_a_worker_is_raised_as_the_serial_run_raises_it():
    def work(i: int) -> int:
        if i == 3:
            raise TwoPartError("fold 3", "no rows left")
        return i

    with pytest.raises(TwoPartError, match="fold 3: no rows left"):
        forked_map(work, range(6), "failing", workers=2)


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="no CPU affinity here")
def test_usable_cores_follows_this_process_affinity_not_the_machine():
    """A container or taskset may give the process fewer cores than the machine has."""
    before = os.sched_getaffinity(0)
    try:
        os.sched_setaffinity(0, {min(before)})  # one core, as `taskset -c 0` would
        assert usable_cores() == 1
        assert forked_map(lambda i: os.getpid(), range(3), "one core") == [os.getpid()] * 3
    finally:
        os.sched_setaffinity(0, before)
    assert usable_cores() == len(before)

"""Independent pieces of one job on the machine's cores, in forked worker processes.

The nested folds of ``host train`` are whole trainings, independent of each other and bound by
the Python interpreter (on two threads they took as long as on one), so a second core only
helps from a second process. A forked child inherits the training data and the work's closure
as they are; only an item (a fold's number) goes to it and its result comes back pickled.

The serial loop is the reference: where fork is unavailable, where one core is all there is,
or where anything in the pool fails (an error that does not survive pickling, a child killed),
the same items are run in this process, so an error is raised as the serial run raises it.
"""

from __future__ import annotations

import gc
import multiprocessing
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import TypeVar

from thermal_comp.host.progress import progress

T = TypeVar("T")
R = TypeVar("R")

_WORK: Callable | None = None  # the function the forked workers call: inherited, not pickled


def _call(item):
    assert _WORK is not None, "a worker of forked_map runs only inside it"
    return _WORK(item)


def usable_cores() -> int:
    """The cores this process may run on (its CPU affinity, as a container or taskset sets)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def default_workers(n_items: int) -> int:
    """Processes for ``n_items`` pieces when the caller names none: one, this process. Forked
    workers for the three nested folds of a 24-h run at 1 s paid only on an idle two-core
    machine (0.89x the wall time for 14 % more CPU), were slower than one process under a
    second busy job, and every child's memory counts (three children: 2.8x one process's
    peak RSS). More on request: ``workers`` (``host train --jobs N``; issue 46)."""
    del n_items  # every count: one
    return 1


def forked_map(work: Callable[[T], R], items: Sequence[T], desc: str, *,
               workers: int | None = None, quiet: bool = True) -> list[R]:
    """``[work(x) for x in items]`` with a progress bar, the items spread over at most
    ``workers`` forked processes (default: default_workers); the results in the items'
    order."""
    global _WORK
    items = list(items)
    n = min(len(items), workers if workers is not None else default_workers(len(items)))
    if n >= 2 and "fork" in multiprocessing.get_all_start_methods():
        _WORK = work
        gc.freeze()  # the collector leaves the inherited objects alone: no copy-on-write
        try:
            with ProcessPoolExecutor(n, mp_context=multiprocessing.get_context("fork")) as pool:
                futures = {pool.submit(_call, x): k for k, x in enumerate(items)}
                out: list = [None] * len(items)
                for done in progress(as_completed(futures), desc, total=len(items),
                                     quiet=quiet):
                    out[futures[done]] = done.result()
            return out
        except Exception:  # noqa: BLE001  (the serial run below raises what is wrong)
            pass
        finally:
            _WORK = None
            gc.unfreeze()
    return [work(x) for x in progress(items, desc, quiet=quiet)]

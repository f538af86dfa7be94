"""Progress bars for long work: shown on a terminal, silent in --json mode and in pipes."""

from __future__ import annotations

import sys
from collections.abc import Iterable, Iterator
from typing import TypeVar

T = TypeVar("T")
_QUIET = False


def set_quiet(quiet: bool) -> None:
    """Silence every progress bar of this process (``host -q`` / ``--quiet``)."""
    global _QUIET
    _QUIET = bool(quiet)


def progress(items: Iterable[T], desc: str, total: int | None = None,
             quiet: bool = False) -> Iterator[T]:
    """Wrap an iterable with a tqdm bar on stderr unless quiet or stderr is not a terminal.
    tqdm is imported only for a bar that shows: ~40 ms of every command's start otherwise."""
    if quiet or _QUIET or not sys.stderr.isatty():
        yield from items
        return
    from tqdm import tqdm

    # no monitor thread (it only retunes refresh rates): host.parallel forks this process,
    # and a fork copies a lock a running thread may hold
    tqdm.monitor_interval = 0
    yield from tqdm(items, desc=desc, total=total, leave=False, file=sys.stderr,
                    dynamic_ncols=True)

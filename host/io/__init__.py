"""Run I/O: thermal test runs (CSV) in and out, and cutting a run in two.
"""

from __future__ import annotations

from host.io.runs import TIME_COLUMN, Run, RunFormatError, load_run, load_runs, write_run
from host.io.split import split_file, window

__all__ = [
    "Run",
    "RunFormatError",
    "TIME_COLUMN",
    "load_run",
    "load_runs",
    "split_file",
    "window",
    "write_run",
]

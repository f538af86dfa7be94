"""Run I/O: thermal test runs (CSV) in and out, and cutting a run in two.
"""

from __future__ import annotations

from thermal_comp.host.io.runs import (
    DISP_UNITS,
    TEMP_UNITS,
    TIME_COLUMN,
    TIME_UNITS,
    CsvFormat,
    Run,
    RunFormatError,
    check_variation,
    load_run,
    load_runs,
    missing_sensors,
    read_header,
    read_table,
    write_run,
)
from thermal_comp.host.io.split import split_file, window

__all__ = [
    "CsvFormat",
    "DISP_UNITS",
    "Run",
    "RunFormatError",
    "TEMP_UNITS",
    "TIME_COLUMN",
    "TIME_UNITS",
    "check_variation",
    "load_run",
    "load_runs",
    "missing_sensors",
    "read_header",
    "read_table",
    "split_file",
    "window",
    "write_run",
]

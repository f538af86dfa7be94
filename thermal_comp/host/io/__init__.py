"""Run I/O: thermal test runs (CSV) in and out, and cutting a run in two.

The wing's one face: other wings import from here. Its rooms, one job each: ``run`` (the Run
type), ``format_error``, ``csv_format`` (the dialect and its sniffing), ``table`` (with
``fast_table``, ``plain_numbers`` and ``cells``), ``columns``, ``time_checks``,
``value_ranges``, ``unit_sniffing``, ``gap_filling``, ``load``, ``variation``, ``write``,
``split``.
"""

from __future__ import annotations

from thermal_comp.host.io.columns import missing_sensors
from thermal_comp.host.io.csv_format import DISP_UNITS, TEMP_UNITS, TIME_UNITS, CsvFormat
from thermal_comp.host.io.format_error import RunFormatError
from thermal_comp.host.io.load import load_run, load_runs
from thermal_comp.host.io.run import TIME_COLUMN, Run
from thermal_comp.host.io.split import split_file, window
from thermal_comp.host.io.table import read_header, read_table
from thermal_comp.host.io.variation import check_variation
from thermal_comp.host.io.write import write_run

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

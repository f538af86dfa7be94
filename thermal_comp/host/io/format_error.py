"""The one refusal of a run file: its message names file, line and column, so whoever wrote
the file finds the cell without reading the code."""

from __future__ import annotations

from pathlib import Path

from thermal_comp.contract.errors import InputError


class RunFormatError(InputError):
    """A run file cannot be used; the message names file, line and column."""

    def __init__(self, path: str | Path, message: str, line: int | None = None,
                 column: str | None = None) -> None:
        where = str(path)
        if line is not None:
            where += f", line {line}"
        if column is not None:
            where += f", column '{column}'"
        super().__init__(f"{where}: {message}")
        self.path = str(path)
        self.line = line
        self.column = column

"""`host monitor --log`: the samples as a CSV run, invalid readings left empty and named in a
faults column."""

from __future__ import annotations

import csv
from pathlib import Path
from typing import TextIO

from thermal_comp.host.box.state import MonitorError, MonitorState


class CsvLog:
    """Appends samples as CSV; the header is fixed by the first sample's layout and checked
    against an existing file so two layouts never mix in one log.

    A faulted channel's reading is not a temperature: its cell is left empty (what a run file
    calls a missing value) and the ``faults`` column says why (``T12=OPEN``; ``T05=OPEN?`` for
    every channel while the box has raised OPEN and STATUS has not yet said which one)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._fh: TextIO | None = None
        self._writer = None
        self.header: list[str] | None = None

    def write(self, state: MonitorState, received: float) -> None:
        s = state.sample
        assert s is not None
        period_s = state.info.period_ms / 1000.0 if state.info else 1.0
        header = (["time_s", "seq", "status"]
                  + [f"corr_{n}" for n in state.axis_names(len(s.corrections_nm))]
                  + state.channel_names(len(s.temp_codes)) + ["faults", "host_unix_s"])
        if self._fh is None:
            self._open(header)
        elif header != self.header:
            raise MonitorError(f"{self.path}: the box's layout changed ({', '.join(header)}); "
                               "start a new --log file")
        assert self._writer is not None and self._fh is not None
        invalid = state.invalid_channels()
        names = state.channel_names(len(s.temp_codes))
        self._writer.writerow([f"{s.seq * period_s:.6g}", s.seq, f"{s.status:04X}"]
                              + [f"{nm / 1000.0:.3f}" for nm in s.corrections_nm]
                              + ["" if n in invalid else f"{c / 128.0:.4f}"
                                 for n, c in zip(names, s.temp_codes, strict=True)]
                              + [";".join(f"{n}={why}" for n, why in invalid.items()),
                                 f"{received:.3f}"])
        self._fh.flush()

    def _open(self, header: list[str]) -> None:
        existing = None
        if self.path.is_file() and self.path.stat().st_size > 0:
            with self.path.open(newline="") as fh:
                existing = next(csv.reader(fh), None)
            if existing != header:
                raise MonitorError(f"{self.path}: existing log has columns "
                                   f"{', '.join(existing or [])}, the box sends "
                                   f"{', '.join(header)}; use another --log file")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fh = self.path.open("a", newline="")
        self._writer = csv.writer(self._fh)
        if existing is None:
            self._writer.writerow(header)
        self.header = header

    def close(self) -> None:
        if self._fh is not None:
            self._fh.close()

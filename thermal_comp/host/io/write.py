"""Write a run in the project's own CSV format, the one every reader here reads without a
guess (``,``, decimal point, ``time_s`` in seconds)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from thermal_comp.host.io.run import TIME_COLUMN


def write_run(path: str | Path, time_s: np.ndarray, columns: dict[str, np.ndarray],
              precision: int = 6) -> None:
    """Write a run in the project's CSV format (atomic: temp file then rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    names = [TIME_COLUMN, *columns]
    table = np.column_stack([time_s, *columns.values()])
    with tmp.open("w", newline="") as fh:
        fh.write(",".join(names) + "\n")
        fmt = f"%.{precision}g"
        np.savetxt(fh, table, delimiter=",", fmt=fmt)
    tmp.replace(path)

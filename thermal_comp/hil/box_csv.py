"""What the box sent for every sample, as a CSV anyone can open.

A glitch's effect on the output can then be looked at without the runner or the report.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from thermal_comp.hil.expect import status_text
from thermal_comp.hil.feed import Feed
from thermal_comp.hil.replay_report import ReplayReport


def write_box_csv(report: ReplayReport, feed: Feed, path: str | Path) -> Path:
    """What the box sent for every sample: ``time_s, session, seq, status, status_names`` and
    the correction of each axis in um (empty where no line arrived). Anyone can look at a
    glitch's effect without the runner."""
    import csv

    path = Path(path)
    n = report.samples
    status = report.fw_status if report.fw_status is not None else np.full(n, -1)
    seq = report.fw_seq if report.fw_seq is not None else np.full(n, -1)
    session = report.fw_session if report.fw_session is not None else np.full(n, -1)
    out = report.fw_out_nm if report.fw_out_nm is not None else np.zeros((n, len(feed.axes)))
    time_s = feed.run.time_s
    with path.open("w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(["time_s", "session", "seq", "status", "status_names",
                    *[f"{a}" for a in feed.axes]])
        for i in range(n):
            if status[i] < 0:
                w.writerow([f"{time_s[i]:.6g}", "", "", "", "", *[""] * len(feed.axes)])
                continue
            w.writerow([f"{time_s[i]:.6g}", int(session[i]), int(seq[i]),
                        f"{int(status[i]):04X}", status_text(int(status[i])),
                        *[f"{v / 1000:.3f}" for v in out[i]]])
    return path

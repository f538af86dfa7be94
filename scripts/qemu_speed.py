"""Where the QEMU replay's time goes (docs/hil.md, "Speed"): the same feed through the STM32
image with every sample line sent, then with RATE N-1 (a line for the first and the last
sample only), so the cost of a byte in and a byte out can be told apart.

    .venv/bin/python scripts/qemu_speed.py [N]      (N samples of the FL head, default 3000)
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from firmware_support import prepare_fl_head  # noqa: E402

from thermal_comp.hil import qemu  # noqa: E402


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 3000
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        setup = prepare_fl_head(d, n)
        elf = qemu.build_image(setup.build.header_path, d / "img")
        lines = setup.feed.feed_lines()
        feed_bytes = sum(len(line) for line in lines)
        for rate in (1, n - 1):
            box = qemu.QemuBox(elf)
            try:
                if rate != 1:
                    box.link.command(f"RATE {rate}", b"$OK,RATE", 5)
                t0 = time.perf_counter()
                sent, window, chunk = 0, 200, 50
                while sent < n:  # at most `window` samples in flight, as the runner does
                    box.link.wait_prefixed(max(0, (sent - window) // rate), 60, "lines")
                    box.feed(b"".join(lines[sent:sent + chunk]))
                    sent += chunk
                box.link.wait_prefixed(n if rate == 1 else 2, 120, "the last sample's line")
                dt = time.perf_counter() - t0
                out = sum(len(line) + 2 for line in box.link.lines)
                print(f"RATE {rate:>5}: {n} samples in {dt:.2f} s = {n / dt:,.0f} samples/s; "
                      f"in {feed_bytes / n:.0f} B/sample, out {out / n:.1f} B/sample")
            finally:
                box.kill()


if __name__ == "__main__":
    main()

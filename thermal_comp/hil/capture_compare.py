"""Two replays of one feed compared line for line (the QEMU build against the native one).

The sample lines must agree byte for byte: one firmware, two machines.
"""

from __future__ import annotations

from thermal_comp.hil.runner import Capture


def sample_lines(capture: Capture) -> list[bytes]:
    """Every sample line of a capture, in order, as sent (all sessions)."""
    return [raw for s in capture.sessions for raw in s.lines if raw.startswith(b"$C,")]


def capture_differences(a: Capture, b: Capture) -> tuple[int, str]:
    """(number of sample lines that differ byte for byte, first difference) of two replays."""
    la, lb = sample_lines(a), sample_lines(b)
    diff = sum(1 for x, y in zip(la, lb, strict=False) if x != y) + abs(len(la) - len(lb))
    first = ""
    for i, (x, y) in enumerate(zip(la, lb, strict=False)):
        if x != y:
            first = f"sample line {i}: {x!r} vs {y!r}"
            break
    else:
        if len(la) != len(lb):
            first = f"{len(la)} sample lines vs {len(lb)}"
    return diff, first

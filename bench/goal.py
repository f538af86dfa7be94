"""A bench row's goal, machine-checkable: ``{"op": "<=", "value": 10}``, or ``INFO``.

Every row a suite returns carries ``goal`` (what the runner checks) beside ``target`` (the
same goal for a reader, in words: "< 10 s on 2 cores"). A row that is there to inform (a
throughput, a peer's error, the spread behind a ratio) says so with ``INFO``; the runner
shows it as ``info`` and counts it apart. A row without a goal fails, so a new row cannot
slip in unchecked.
"""

from __future__ import annotations

import math
import operator

OPS = {"<": operator.lt, "<=": operator.le, ">": operator.gt, ">=": operator.ge,
       "==": operator.eq}
INFO = {"op": "info"}


def goal(op: str, value: float) -> dict:
    """The goal ``measured <op> value``; ``op`` one of OPS."""
    if op not in OPS:
        raise ValueError(f"goal: {op!r} is not one of {', '.join(OPS)}")
    return {"op": op, "value": value}


def target_text(g: dict, unit: str = "") -> str:
    """The goal in words, for a row that gives no ``target`` of its own."""
    if g.get("op") == "info":
        return ""
    return f"{g['op']} {g['value']:g}" + (f" {unit}" if unit else "")


def verdict(row: dict) -> str:
    """'pass', 'fail', 'info', or 'no goal' (a row without one: counted as a failure)."""
    g = row.get("goal")
    if not isinstance(g, dict) or g.get("op") not in (*OPS, "info"):
        return "no goal"
    if g["op"] == "info":
        return "info"
    value = row.get("value")
    try:
        if value is None or math.isnan(float(value)):
            return "fail"  # not measured is not met
    except (TypeError, ValueError):
        return "fail"
    return "pass" if OPS[g["op"]](float(value), float(g["value"])) else "fail"

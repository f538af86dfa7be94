"""Commands from the broker to a box (``host gateway --allow-commands``): the JSON a user
publishes on ``thermalcomp/<machine>/cmd/<user>`` checked and turned into the box's line. Only
ZERO, STATUS, INFO and RATE n, and none older than ``COMMAND_MAX_AGE_S``: an old command
replayed must not zero a machine.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

from thermal_comp.contract import protocol

COMMAND_MAX_AGE_S = 10.0
COMMANDS = ("ZERO", "STATUS", "INFO", "RATE")


@dataclass
class Command:
    user: str
    text: str
    line: bytes


def parse_command(payload: bytes, now: float) -> tuple[str, bytes]:
    """A command message -> (its text, the line for the box). ``payload``: JSON
    ``{"command": "ZERO", "t": <unix s>}``. Raises ValueError with the reason."""
    try:
        data = json.loads(payload)
    except (ValueError, UnicodeDecodeError):
        raise ValueError("not JSON ({\"command\": \"ZERO\", \"t\": <unix s>})") from None
    if not isinstance(data, dict) or not isinstance(data.get("command"), str):
        raise ValueError("no \"command\" field")
    t = data.get("t")
    if not isinstance(t, int | float) or isinstance(t, bool):
        raise ValueError("no \"t\" (the time it was sent): a command without one could be "
                         "an old one replayed")
    if abs(now - t) > COMMAND_MAX_AGE_S:
        raise ValueError(f"sent {now - t:.0f} s ago (more than {COMMAND_MAX_AGE_S:g} s): "
                         "not executed")
    words = data["command"].split()
    if not words or words[0] not in COMMANDS:
        raise ValueError(f"command {data['command'][:40]!r} is not one of "
                         f"{', '.join(COMMANDS)}")
    try:
        arg = int(words[1]) if len(words) == 2 and words[0] == "RATE" else None
        if len(words) != (2 if words[0] == "RATE" else 1):
            raise ValueError
        line = protocol.encode_command(words[0], arg)
    except (ValueError, protocol.InputError) as exc:
        raise ValueError(f"command {data['command'][:40]!r}: bad argument {exc}") from None
    return " ".join(words), line

"""The fleet's MQTT topics and the JSON on them (docs/fleet.md): what a gateway publishes and
what the fleet service accepts.

Topics, one subtree per machine (``<machine>``: 1-64 of ``A-Z a-z 0-9 _ . -``):

- ``thermalcomp/<machine>/state``  — QoS 1, retained: one JSON object per sample (the box's
  sequence, status names, correction per axis, temperatures, faulted channels, the last probe
  residual, the model hash). Retained, so a new subscriber sees each machine's last state.
- ``thermalcomp/<machine>/event``  — QoS 1: INFO, a model change, a bad or unknown line, a
  probe answer, a command and its outcome.
- ``thermalcomp/<machine>/online`` — QoS 1, retained: ``online``, or ``offline`` (the
  gateway's last will, also sent when it stops).
- ``thermalcomp/<machine>/cmd/<user>`` — a command for the box, read only by a gateway that
  enabled commands for this machine, and only from the users it names; the broker's ACL
  (``pattern write thermalcomp/+/cmd/%u``) makes ``<user>`` the authenticated publisher.

Every state and event carries ``gateway`` (one id per gateway run) and ``n`` (its message
counter): the store keeps each (machine, gateway, n) once, so a message delivered twice (QoS 1
resends, a retained copy on resubscribe) is stored once and a missing ``n`` is a lost message.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from typing import Any

from thermal_comp.contract.errors import InputError

ROOT = "thermalcomp"
SCHEMA = 1
MAX_PAYLOAD = 16 * 1024  # bytes; a box's state is ~1 kB with 32 channels and 6 axes
ONLINE, OFFLINE = "online", "offline"
KINDS = ("state", "event", "online")
MACHINE_RE = re.compile(r"[A-Za-z0-9_.-]{1,64}")
USER_RE = re.compile(r"[A-Za-z0-9_.@-]{1,64}")
EVENT_KINDS = ("info", "model_changed", "bad_line", "unknown_line", "probe", "reply",
               "command", "connected", "lost", "no_info")


class FleetError(InputError):
    """Bad fleet input: a machine name, a broker or database URL, a command line option."""


class Refused(Exception):
    """A message the fleet service does not store; ``reason`` says why (logged, on the
    page)."""

    def __init__(self, reason: str, machine: str | None = None) -> None:
        super().__init__(reason)
        self.reason = reason
        self.machine = machine


def check_machine(name: str) -> str:
    if not MACHINE_RE.fullmatch(name or ""):
        raise FleetError(f"machine name {name!r}: use 1-64 of A-Z a-z 0-9 _ . - (it is a "
                         "topic level)")
    return name


def topic(machine: str, kind: str) -> str:
    return f"{ROOT}/{machine}/{kind}"


def command_topic(machine: str, user: str) -> str:
    return f"{ROOT}/{machine}/cmd/{user}"


@dataclass(frozen=True)
class Message:
    """A message the fleet service accepted: ``kind`` state/event/online, ``data`` the JSON
    object (for online: ``{"online": bool}``)."""

    machine: str
    kind: str
    data: dict[str, Any]


def encode(data: dict[str, Any]) -> bytes:
    return json.dumps(data, separators=(",", ":"), allow_nan=False).encode()


def _finite(obj: Any) -> bool:
    if isinstance(obj, float):
        return math.isfinite(obj)
    if isinstance(obj, dict):
        return all(_finite(v) for v in obj.values())
    if isinstance(obj, list):
        return all(_finite(v) for v in obj)
    return True


def _need(data: dict, key: str, types: type | tuple[type, ...], machine: str,
          optional: bool = False) -> Any:
    value = data.get(key)
    if value is None and optional:
        return None
    allowed = types if isinstance(types, tuple) else (types,)
    if not isinstance(value, allowed) or (isinstance(value, bool) and bool not in allowed):
        names = "/".join(t.__name__ for t in allowed)
        raise Refused(f"field {key!r} missing or not {names}", machine)
    return value


def _numbers(data: dict, key: str, machine: str) -> dict[str, float | None]:
    value = _need(data, key, dict, machine)
    for name, v in value.items():
        if v is not None and (isinstance(v, bool) or not isinstance(v, int | float)):
            raise Refused(f"field {key!r}: {name!r} is not a number", machine)
    return value


def _topic_parts(topic_name: str) -> tuple[str, str] | None:
    """(machine, kind) of a topic the service stores; None for a command's topic."""
    parts = topic_name.split("/")
    if len(parts) < 3 or parts[0] != ROOT:
        raise Refused(f"topic {topic_name!r} is not {ROOT}/<machine>/<kind>")
    machine = parts[1]
    if not MACHINE_RE.fullmatch(machine):
        raise Refused(f"machine name {machine[:80]!r} in topic is not a valid name")
    if parts[2] == "cmd":
        return None
    if len(parts) != 3 or parts[2] not in KINDS:
        raise Refused(f"unknown topic kind {'/'.join(parts[2:])[:80]!r} (known: "
                      f"{', '.join(KINDS)})", machine)
    return machine, parts[2]


def parse(topic_name: str, payload: bytes) -> Message | None:
    """Check one received message. Returns None for a topic the service does not store (a
    command), raises :class:`Refused` with the reason for anything malformed."""
    where = _topic_parts(topic_name)
    if where is None:
        return None
    machine, kind = where
    if len(payload) > MAX_PAYLOAD:
        raise Refused(f"oversized message: {len(payload)} bytes > {MAX_PAYLOAD}", machine)
    if kind == "online":
        text = payload.decode("utf-8", errors="replace").strip()
        if text not in (ONLINE, OFFLINE):
            raise Refused(f"online topic says {text[:40]!r}, not {ONLINE}/{OFFLINE}", machine)
        return Message(machine, kind, {"online": text == ONLINE})
    try:
        data = json.loads(payload)
    except (ValueError, UnicodeDecodeError) as exc:
        raise Refused(f"malformed JSON: {str(exc)[:80]}", machine) from None
    if not isinstance(data, dict):
        raise Refused("malformed message: not a JSON object", machine)
    if data.get("schema") != SCHEMA:
        raise Refused(f"schema {data.get('schema')!r} is not {SCHEMA}", machine)
    if data.get("machine") != machine:
        raise Refused(f"message names machine {str(data.get('machine'))[:64]!r} but came on "
                      f"{machine!r}'s topic", machine)
    if not _finite(data):
        raise Refused("a number is not finite", machine)
    _need(data, "gateway", str, machine)
    n = _need(data, "n", int, machine)
    t = _need(data, "t", (int, float), machine)
    if n < 0 or t <= 0:
        raise Refused(f"n {n} or t {t} out of range", machine)
    if kind == "state":
        _check_state(data, machine)
    else:
        event = _need(data, "event", str, machine)
        if event not in EVENT_KINDS:
            raise Refused(f"unknown event {event[:40]!r}", machine)
        _need(data, "message", str, machine)
    return Message(machine, kind, data)


def _check_state(data: dict, machine: str) -> None:
    """A state's own fields: sequence, status word, flag names, numbers per axis and channel,
    faults, and the optional model hash, period and probe residual."""
    seq = _need(data, "seq", int, machine)
    if not 0 <= seq < 2**32:
        raise Refused(f"seq {seq} outside 0..2^32-1", machine)
    status = _need(data, "status", str, machine)
    if not re.fullmatch(r"[0-9A-F]{4}", status):
        raise Refused(f"status {status[:10]!r} is not 4 hex digits", machine)
    flags = _need(data, "flags", list, machine)
    if not all(isinstance(f, str) for f in flags):
        raise Refused("flags are not names", machine)
    _numbers(data, "corrections_um", machine)
    _numbers(data, "temperatures_c", machine)
    _need(data, "faults", dict, machine)
    _need(data, "model_hash", str, machine, optional=True)
    _need(data, "period_ms", int, machine, optional=True)
    probe = _need(data, "probe", dict, machine, optional=True)
    if probe is not None:
        _numbers(probe, "residual_um", machine)

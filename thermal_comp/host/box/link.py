"""The serial side of `host monitor`: opening the port, telling a reappearing device by its
identity (serial number, or none for a pty), and the ``LineView`` hook that sees the box's
lines as received (``host monitor --mqtt``: the fleet gateway's relay)."""

from __future__ import annotations

import os
from typing import Protocol

import serial


def open_port(port: str, baud: int) -> serial.SerialBase:
    """A pyserial port (device path, pty, or a pyserial URL such as socket://host:port)."""
    if "://" in port:
        return serial.serial_for_url(port, baudrate=baud, timeout=0.05)
    return serial.Serial(port, baudrate=baud, timeout=0.05)


def device_identity(port: str) -> str | None:
    """What the device at ``port`` says it is without being asked: a USB adapter's serial
    number (vendor:product:serial). None for a pty, a URL or an adapter without a serial
    number: such a device can only be known by its INFO answer."""
    if "://" in port:
        return None
    try:
        from serial.tools import list_ports

        real = os.path.realpath(port)
        for p in list_ports.comports():
            if os.path.realpath(p.device) == real and p.serial_number:
                return f"{p.vid or 0:04x}:{p.pid or 0:04x}:{p.serial_number}"
    except (OSError, ImportError):
        return None
    return None


class LineView(Protocol):
    """A view fed the box's lines as received (every one, good or bad) and the serial link's
    coming and going, with wall-clock times; ``start`` before the first, ``stop`` at the end.
    host.fleet.gateway.BoxRelay is one (the MQTT publisher of ``host monitor --mqtt``)."""

    def start(self) -> None: ...

    def line(self, raw: bytes, now: float) -> object: ...

    def connected(self, port: str, now: float) -> None: ...

    def lost(self, why: str, now: float) -> None: ...

    def stop(self) -> None: ...

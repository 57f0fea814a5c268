"""Opening a pyserial URL (real port, socket://host:port, loop://) with errors a person can act on."""

from __future__ import annotations

import serial

from arproj.devices.errors import DeviceError


def open_url(url: str, baudrate: int = 9600, timeout_s: float = 0.2, what: str = "device") -> serial.SerialBase:
    """An open pyserial port for url; DeviceError naming the URL when it cannot be opened."""
    try:
        return serial.serial_for_url(url, baudrate=baudrate, timeout=timeout_s, write_timeout=timeout_s)
    except (serial.SerialException, ValueError, OSError) as err:
        raise DeviceError(f"cannot open the {what} at {url!r}: {err}",
                          "check the cable, the port name (e.g. /dev/ttyUSB0) or the socket:// address, "
                          "or pass --sim") from None

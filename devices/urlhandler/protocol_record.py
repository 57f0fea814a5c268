"""`record://URL?file=F`: a pyserial port that passes everything to URL and writes it to F in spy://'s hexdump
format (devices/recording.py)."""

from __future__ import annotations

import urllib.parse
from typing import Any

import serial
from serial.urlhandler.protocol_spy import FormatHexdump

from devices.recording import start_recording


def split_url(url: str) -> tuple[str, str]:
    """(inner URL, recording file) of `record://URL?file=F`."""
    if not url.lower().startswith("record://"):
        raise serial.SerialException(f"expected record://URL?file=FILE, got {url!r}")
    inner, _, query = url[len("record://"):].rpartition("?")
    files = urllib.parse.parse_qs(query).get("file")
    if not inner or not files:
        raise serial.SerialException(f"expected record://URL?file=FILE, got {url!r}")
    return inner, files[0]


class Serial(serial.SerialBase):  # type: ignore[misc]  # pyserial is untyped
    """Wraps the port of the inner URL (opened with the same settings)."""

    def open(self) -> None:
        if self.is_open:  # type: ignore[has-type]
            raise serial.SerialException("port already open")
        inner_url, path = split_url(str(self.port))
        self._inner = serial.serial_for_url(inner_url, baudrate=self.baudrate, timeout=self.timeout,
                                            write_timeout=self.write_timeout)
        self._out = open(path, "w" if start_recording(path) else "a")  # noqa: SIM115 (closed in close())
        self._format = FormatHexdump(self._out, False)
        self._format.control("OPEN", inner_url)
        self.is_open = True

    def close(self) -> None:
        if self.is_open:
            self.is_open = False
            self._inner.close()
            self._out.close()

    def _reconfigure_port(self) -> None:
        if self.is_open:
            self._inner.timeout = self.timeout

    @property
    def in_waiting(self) -> int:
        return int(self._inner.in_waiting)

    def read(self, size: int = 1) -> bytes:
        try:
            data = bytes(self._inner.read(size))
        except serial.SerialException:
            self._format.control("EOF", "the device went away")
            raise
        if data:
            self._format.rx(data)
        return data

    def write(self, data: Any) -> int | None:
        data = serial.to_bytes(data)
        self._format.tx(data)
        return self._inner.write(data)

    def reset_input_buffer(self) -> None:
        self._inner.reset_input_buffer()

    def reset_output_buffer(self) -> None:
        self._inner.reset_output_buffer()

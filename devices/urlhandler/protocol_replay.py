"""`replay://F`: a pyserial port that plays a recording back (devices/recording.py)."""

from __future__ import annotations

import time
from typing import Any

import serial

from devices.recording import Connection, replay_session


class Serial(serial.SerialBase):  # type: ignore[misc]  # pyserial is untyped
    """One recorded connection of F per open."""

    def open(self) -> None:
        if self.is_open:  # type: ignore[has-type]
            raise serial.SerialException("port already open")
        url = str(self.port)
        if not url.lower().startswith("replay://"):
            raise serial.SerialException(f"expected replay://FILE, got {url!r}")
        self._path = url[len("replay://"):]
        connection = replay_session(self._path).next_connection()
        if connection is None:
            raise serial.SerialException(f"replay of {self._path}: no more recorded connections")
        self._connection: Connection = connection
        self.is_open = True

    def close(self) -> None:
        self.is_open = False

    def _reconfigure_port(self) -> None:
        return

    @property
    def in_waiting(self) -> int:
        return 0

    def read(self, size: int = 1) -> bytes:
        if not self.is_open:
            raise serial.PortNotOpenError()
        data = self._connection.read(size)
        if data is None:
            self.is_open = False
            raise serial.SerialException(f"replay of {self._path}: the device went away here (recorded EOF)")
        if not data and self.timeout:
            time.sleep(self.timeout)  # nothing was recorded here: the host waits as it would for a silent device
        return data

    def write(self, data: Any) -> int:
        if not self.is_open:
            raise serial.PortNotOpenError()
        data = serial.to_bytes(data)
        self._connection.write(data, self._path)
        return len(data)

    def reset_input_buffer(self) -> None:
        return

    def reset_output_buffer(self) -> None:
        return

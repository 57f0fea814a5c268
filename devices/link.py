"""Line-framed serial transport over a pyserial URL (a real port, `socket://host:port`, `loop://`).

Framing and recovery: bytes in, lines out, with a deadline on every read, reconnection when the device goes
away, and `exchange()`, the one retry loop for request/answer protocols. The protocols (GRBL in
scanner/grbl.py, the wall scanner in scanner/wallscanner.py) sit on top and say only what their lines mean.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable
from typing import TypeVar

import serial

from geometry.errors import InputError

POLL_S = 0.01  # granularity of the read deadline
MAX_LINE_BYTES = 4096  # longer "lines" are garbage: dropped so a device spewing noise cannot exhaust memory


class LinkError(InputError):
    """The device cannot be reached (after reconnect attempts) or keeps failing: a person must look."""


class LinkTimeoutError(Exception):
    """No complete line arrived before the deadline (recoverable: the protocol retries)."""


class DisconnectedError(Exception):
    """The transport went away (recoverable: reconnect, then the protocol resynchronises)."""


class DeviceResetError(Exception):
    """The device was reset or reconnected: state (position, buffers) was lost; redo the current step."""


class RequestDamagedError(Exception):
    """The device says our request arrived damaged: `exchange()` sends it again."""


Answer = TypeVar("Answer")


class SerialLink:
    """A line-oriented connection to one device.

    url : pyserial URL; timeout_s : default deadline for one response line; reconnect_attempts and
    reconnect_delay_s bound how long a vanished device is waited for (never a hang).
    """

    def __init__(self, url: str, name: str = "device", timeout_s: float = 0.5, baudrate: int = 115200,
                 reconnect_attempts: int = 50, reconnect_delay_s: float = 0.02) -> None:
        self.url = url
        self.name = name
        self.timeout_s = timeout_s
        self.baudrate = baudrate
        self.reconnect_attempts = reconnect_attempts
        self.reconnect_delay_s = reconnect_delay_s
        self.lock = threading.RLock()
        self.reconnects = 0  # protocols compare this to notice that the device was reset
        self._port: serial.SerialBase | None = None
        self._buffer = bytearray()
        self.garbage_lines = 0
        self.faults_recovered = 0  # timeouts, resends and reconnects that exchange() got over

    # ------------------------------------------------------------------ connection
    def open(self) -> None:
        try:
            self._port = serial.serial_for_url(self.url, baudrate=self.baudrate, timeout=POLL_S,
                                               write_timeout=self.timeout_s)
        except (serial.SerialException, ValueError, OSError) as err:
            raise DisconnectedError(f"{self.name} at {self.url}: {err}") from None
        self._buffer.clear()

    def close(self) -> None:
        if self._port is not None:
            with contextlib.suppress(serial.SerialException, OSError):
                self._port.close()
            self._port = None

    def reconnect(self) -> None:
        """Close and reopen with bounded retries; raises LinkError when the device does not come back."""
        self.close()
        last = ""
        for attempt in range(self.reconnect_attempts):
            time.sleep(self.reconnect_delay_s * min(1 + attempt, 10))
            try:
                self.open()
                self.reconnects += 1
                return
            except DisconnectedError as err:
                last = str(err)
        raise LinkError(f"{self.name} at {self.url} did not come back after {self.reconnect_attempts} attempts "
                        f"({last})", "check the cable and power of the device, then resume the scan")

    def __enter__(self) -> SerialLink:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ request / answer
    def exchange(self, request: Callable[[], str], answer: Callable[[str], Answer | None], *, retries: int,
                 on_reconnect: Callable[[], Exception], timeout_s: float | None = None) -> Answer:
        """Send request() and give each line that comes back to answer() until it returns a value.

        answer returns None to keep listening (noise, a stale line), raises RequestDamagedError when the
        device reports the request damaged, and raises the protocol's own errors for what a person must see.
        A timeout or a RequestDamagedError sends a fresh request() again, at most `retries` times more, then
        LinkError. A disconnect reconnects and raises the error on_reconnect() returns, once the protocol has
        dropped the state the device lost. Holds the lock for the whole exchange, so no other request's lines
        are taken for ours.
        """
        last_fault, line = "", ""
        with self.lock:
            for _ in range(retries + 1):
                try:
                    self.drain()
                    line = request()
                    self.write_line(line)
                    while (value := answer(self.read_line(timeout_s))) is None:
                        pass
                    return value
                except (LinkTimeoutError, RequestDamagedError) as fault:
                    self.faults_recovered += 1
                    last_fault = str(fault)
                except DisconnectedError:
                    self.faults_recovered += 1
                    self.reconnect()
                    raise on_reconnect() from None
        raise LinkError(f"{self.name} at {self.url}: no valid answer to {line!r} after {retries + 1} tries "
                        f"(last: {last_fault})",
                        "check the connection (cable, baud rate, power), then resume")

    # ------------------------------------------------------------------ lines
    def write_line(self, text: str) -> None:
        if self._port is None:
            raise DisconnectedError(f"{self.name}: not open")
        try:
            self._port.write(text.encode("ascii", errors="replace") + b"\n")
        except (serial.SerialException, OSError) as err:
            raise DisconnectedError(f"{self.name}: write failed ({err})") from None

    def read_line(self, timeout_s: float | None = None) -> str:
        """The next complete line (without newline), decoded leniently. Raises LinkTimeoutError / DisconnectedError."""
        deadline = time.monotonic() + (self.timeout_s if timeout_s is None else timeout_s)
        while True:
            newline = self._buffer.find(b"\n")
            if newline >= 0:
                raw = bytes(self._buffer[:newline])
                del self._buffer[:newline + 1]
                return raw.decode("ascii", errors="replace").strip("\r")
            if len(self._buffer) > MAX_LINE_BYTES:
                self._buffer.clear()
                self.garbage_lines += 1
            if time.monotonic() >= deadline:
                raise LinkTimeoutError(f"{self.name}: no response within {timeout_s or self.timeout_s:.3g} s")
            if self._port is None:
                raise DisconnectedError(f"{self.name}: not open")
            try:
                chunk = self._port.read(1)  # waits up to the port's 10 ms timeout
                if chunk:  # then take everything already there without waiting (socket:// in_waiting is 0/1)
                    self._port.timeout = 0
                    chunk += self._port.read(65536)
                    self._port.timeout = POLL_S
            except (serial.SerialException, OSError) as err:
                raise DisconnectedError(f"{self.name}: read failed ({err})") from None
            if chunk:
                self._buffer.extend(chunk)

    def drain(self) -> list[str]:
        """Discard (and return) whatever complete lines are already waiting: stale responses after a retry."""
        lines = []
        if self._port is None:
            return lines
        try:
            self._port.timeout = 0
            self._buffer.extend(self._port.read(65536))
            self._port.timeout = POLL_S
        except (serial.SerialException, OSError) as err:
            raise DisconnectedError(f"{self.name}: read failed ({err})") from None
        while (newline := self._buffer.find(b"\n")) >= 0:
            lines.append(bytes(self._buffer[:newline]).decode("ascii", errors="replace"))
            del self._buffer[:newline + 1]
        return lines

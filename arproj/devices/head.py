"""Driver of the beamer's pan/tilt head over Pelco-D (absolute positioning), transport by pyserial URL.

Every query has a timeout and is retried; a move is confirmed by reading the position back, so a head that
stalls, slips in its encoder or ignores commands is reported instead of silently assumed to be in place.
Roll is not a Pelco-D axis: this head's roll joint is fixed (always 0° commanded).
"""

from __future__ import annotations

import contextlib
import threading
import time
from types import TracebackType

import serial

from arproj.devices import pelco_d
from arproj.devices.errors import DeviceError, DeviceTimeoutError
from arproj.devices.transport import open_url

DEFAULT_TIMEOUT_S = 0.2
DEFAULT_RETRIES = 3
POSITION_TOLERANCE_DEG = 0.015  # just over the protocol's 0.01° resolution
DEFAULT_SETTLE_TIMEOUT_S = 10.0
POLL_INTERVAL_S = 0.02


class PanTiltHead:
    """A Pelco-D pan/tilt head at a pyserial URL.

    >>> with PanTiltHead("socket://127.0.0.1:4001") as head:
    ...     head.move_to(10.0, -5.0)        # returns the (pan, tilt) the head reports, degrees
    """

    def __init__(self, url: str, address: int = 1, baudrate: int = 9600, timeout_s: float = DEFAULT_TIMEOUT_S,
                 retries: int = DEFAULT_RETRIES, settle_timeout_s: float = DEFAULT_SETTLE_TIMEOUT_S) -> None:
        self.url = url
        self.address = address
        self.timeout_s = timeout_s
        self.retries = retries
        self.settle_timeout_s = settle_timeout_s
        self.baudrate = baudrate
        self._port: serial.SerialBase | None = open_url(url, baudrate, timeout_s, what="pan/tilt head")
        self.reconnects = 0
        self._decoder = pelco_d.FrameDecoder()
        self._lock = threading.Lock()
        self.retries_used = 0  # how many resends were needed so far (for diagnostics)
        self.commanded: tuple[float, float] | None = None

    # -- context manager -------------------------------------------------------------------------------
    def __enter__(self) -> PanTiltHead:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def close(self) -> None:
        if self._port is not None:
            self._port.close()
            self._port = None

    # -- protocol --------------------------------------------------------------------------------------
    def _send(self, command2: int, data: int = 0) -> None:
        if self._port is None:
            raise DeviceError(f"pan/tilt head at {self.url!r} is closed")
        try:
            self._port.write(pelco_d.encode(self.address, command2, data))
            self._port.flush()
        except (serial.SerialException, OSError) as err:
            raise DeviceError(f"pan/tilt head at {self.url!r}: write failed ({err})",
                              "check the cable and power of the head") from None

    def _await_reply(self, reply_command: int) -> pelco_d.Frame | None:
        """The first frame from our address with reply_command within the timeout, else None."""
        assert self._port is not None
        deadline = time.monotonic() + self.timeout_s
        while time.monotonic() < deadline:
            try:
                chunk = self._port.read(max(1, self._port.in_waiting))
            except (serial.SerialException, OSError) as err:
                raise DeviceError(f"pan/tilt head at {self.url!r}: read failed ({err})",
                                  "check the cable and power of the head") from None
            for frame in self._decoder.feed(chunk):
                if frame.address == self.address and frame.command2 == reply_command:
                    return frame
        return None

    def _reconnect(self) -> None:
        """Reopen the port once (a head that was unplugged and plugged back in, a socket that dropped)."""
        if self._port is not None:
            with contextlib.suppress(serial.SerialException, OSError):
                self._port.close()
        self._port = open_url(self.url, self.baudrate, self.timeout_s, what="pan/tilt head")
        self._decoder = pelco_d.FrameDecoder()
        self.reconnects += 1

    def _query(self, query_command: int) -> float:
        reply_command = pelco_d.REPLY_FOR_QUERY[query_command]
        name = "pan" if query_command == pelco_d.QUERY_PAN else "tilt"
        with self._lock:
            for attempt in range(self.retries + 1):
                if attempt:
                    self.retries_used += 1
                try:
                    if self._port is not None:  # drop stale replies of an earlier, timed-out query
                        self._port.reset_input_buffer()
                    self._send(query_command)
                    frame = self._await_reply(reply_command)
                except DeviceError:
                    if attempt == self.retries:
                        raise
                    with contextlib.suppress(DeviceError):
                        self._reconnect()
                    continue
                if frame is not None:
                    return pelco_d.data_to_angle(frame.data)
        raise DeviceTimeoutError(
            f"pan/tilt head at {self.url!r} (address {self.address}) did not answer the {name} query "
            f"after {self.retries + 1} tries of {self.timeout_s:.2f} s",
            "check power, cable, baud rate and the head's Pelco-D address")

    # -- public API ------------------------------------------------------------------------------------
    def position(self) -> tuple[float, float]:
        """(pan, tilt) in degrees as the head reports them."""
        return self._query(pelco_d.QUERY_PAN), self._query(pelco_d.QUERY_TILT)

    def command(self, pan_deg: float, tilt_deg: float) -> None:
        """Send the absolute position without waiting."""
        with self._lock:
            self._send(pelco_d.SET_PAN, pelco_d.angle_to_data(pan_deg))
            self._send(pelco_d.SET_TILT, pelco_d.angle_to_data(tilt_deg))
        self.commanded = (pelco_d.data_to_angle(pelco_d.angle_to_data(pan_deg)),
                          pelco_d.data_to_angle(pelco_d.angle_to_data(tilt_deg)))

    def move_to(self, pan_deg: float, tilt_deg: float) -> tuple[float, float]:
        """Move and wait until the reported position is within tolerance; returns the reported (pan, tilt).

        The command is resent when the head stops short (a lost set command); DeviceError when it never
        gets there within settle_timeout_s.
        """
        self.command(pan_deg, tilt_deg)
        assert self.commanded is not None
        target = self.commanded
        deadline = time.monotonic() + self.settle_timeout_s
        last = self.position()
        resend_after = time.monotonic() + 0.5
        while time.monotonic() < deadline:
            if _angle_diff(last[0], target[0]) <= POSITION_TOLERANCE_DEG and \
                    _angle_diff(last[1], target[1]) <= POSITION_TOLERANCE_DEG:
                return last
            time.sleep(POLL_INTERVAL_S)
            previous, last = last, self.position()
            if last == previous and time.monotonic() > resend_after:  # not moving: the command may be lost
                self.retries_used += 1
                self.command(*target)
                resend_after = time.monotonic() + 0.5
        raise DeviceError(
            f"pan/tilt head at {self.url!r} did not reach pan {target[0]:.2f}°, tilt {target[1]:.2f}° within "
            f"{self.settle_timeout_s:.1f} s (it reports pan {last[0]:.2f}°, tilt {last[1]:.2f}°)",
            "check that nothing blocks the head and that its limits allow this position")


def _angle_diff(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)

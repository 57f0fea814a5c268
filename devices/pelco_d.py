"""Pelco-D: its 7-byte framing, the absolute-positioning commands of a pan/tilt head, and the head's driver
(`PanTiltHead`) over a SerialLink.

A Pelco-D message is 7 bytes:  0xFF, address, command1, command2, data1, data2, checksum
where checksum = (address + command1 + command2 + data1 + data2) mod 256. Absolute positioning
(the "extended" command set most heads implement):

    set pan position   cmd2 0x4B   data = pan  in hundredths of a degree, 0 … 35999
    set tilt position  cmd2 0x4D   data = tilt in hundredths of a degree, negative tilt as 36000 + tilt
    query pan          cmd2 0x51   → reply cmd2 0x59 with the pan position in data
    query tilt         cmd2 0x53   → reply cmd2 0x5B with the tilt position in data

Angles therefore have a resolution of 0.01°. Heads differ in whether they acknowledge set commands; this
driver does not rely on it: it confirms a move by querying the position.

The driver: every query has a timeout and is retried; a move is confirmed by reading the position back, so a
head that stalls, slips in its encoder or ignores commands is reported instead of silently assumed to be in
place. Roll is not a Pelco-D axis: this head's roll joint is fixed (always 0° commanded).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from types import TracebackType

import numpy as np

from devices.errors import DeviceError
from devices.link import Noise, SerialLink

SYNC = 0xFF
FRAME_LENGTH = 7

SET_PAN = 0x4B
SET_TILT = 0x4D
QUERY_PAN = 0x51
QUERY_TILT = 0x53
REPLY_PAN = 0x59
REPLY_TILT = 0x5B

REPLY_FOR_QUERY = {QUERY_PAN: REPLY_PAN, QUERY_TILT: REPLY_TILT}

CENTIDEGREES_PER_TURN = 36000

DEFAULT_TIMEOUT_S = 0.2
DEFAULT_RETRIES = 3
POSITION_TOLERANCE_DEG = 0.015  # just over the protocol's 0.01° resolution
DEFAULT_SETTLE_TIMEOUT_S = 10.0
POLL_INTERVAL_S = 0.02
RESEND_AFTER_S = 0.5  # a head that has not moved for this long has probably lost the set command


@dataclass(frozen=True)
class Frame:
    """One decoded Pelco-D message."""

    address: int
    command1: int
    command2: int
    data1: int
    data2: int

    @property
    def data(self) -> int:
        return (self.data1 << 8) | self.data2

    def to_bytes(self) -> bytes:
        body = bytes([self.address, self.command1, self.command2, self.data1, self.data2])
        return bytes([SYNC]) + body + bytes([checksum(body)])


def checksum(body: bytes) -> int:
    """Pelco-D checksum of the 5 bytes after the sync byte."""
    return sum(body) & 0xFF


def message(address: int, command2: int, data: int = 0, command1: int = 0) -> Frame:
    """A message; data is a 16-bit value (data1 = high byte)."""
    if not 0 <= address <= 255:
        raise ValueError(f"Pelco-D address must be 0…255, got {address}")
    if not 0 <= data <= 0xFFFF:
        raise ValueError(f"Pelco-D data must be 0…65535, got {data}")
    return Frame(address, command1, command2, (data >> 8) & 0xFF, data & 0xFF)


def encode(address: int, command2: int, data: int = 0, command1: int = 0) -> bytes:
    """The 7 bytes of a message; data is a 16-bit value (data1 = high byte)."""
    return message(address, command2, data, command1).to_bytes()


def angle_to_data(angle_deg: float) -> int:
    """An angle in degrees (any sign) as Pelco-D hundredths of a degree in 0 … 35999."""
    return round(angle_deg * 100.0) % CENTIDEGREES_PER_TURN


def data_to_angle(data: int, signed: bool = True) -> float:
    """Pelco-D hundredths of a degree back to degrees; signed maps 180° … 360° to -180° … 0°."""
    centi = data % CENTIDEGREES_PER_TURN
    if signed and centi >= CENTIDEGREES_PER_TURN // 2:
        centi -= CENTIDEGREES_PER_TURN
    return centi / 100.0


class PelcoDFramer:
    """Turns a byte stream into frames and back: resynchronises on 0xFF and drops bytes whose checksum fails.

    Garbage, truncated frames and corrupted bytes are counted in `rejected_bytes`, never raised: the caller
    decides by timeout whether an answer came.
    """

    terminator = b""
    # any byte, 0xFF (sync) included; endless sync bytes are the framer's worst case (each one starts a frame)
    noise = Noise(insert=(0, 256), junk=(0, 256), junk_length=(1, 9), endless=bytes([SYNC]))

    def __init__(self) -> None:
        self._buffer = bytearray()
        self.rejected_bytes = 0

    def feed(self, data: bytes) -> list[Frame]:
        # Vectorised: a frame starts at a sync byte whose checksum holds. A byte-by-byte resync loop spent
        # ~1 s of Python per MiB on a device flooding sync bytes, holding a read far past its deadline.
        self._buffer.extend(data)
        buf = np.frombuffer(bytes(self._buffer), dtype=np.uint8)
        n = len(buf)
        frames: list[Frame] = []
        pos = 0  # everything before pos is a frame taken or a byte rejected
        if n >= FRAME_LENGTH:
            starts = n - FRAME_LENGTH + 1
            sums = np.concatenate((np.zeros(1, np.uint8), np.cumsum(buf, dtype=np.uint8)))  # wraps: mod 256
            body_sum = sums[6:6 + starts] - sums[1:1 + starts]
            for i in np.flatnonzero((buf[:starts] == SYNC) & (body_sum == buf[6:6 + starts])).tolist():
                if i >= pos:  # not inside the frame just taken
                    frames.append(Frame(*buf[i + 1:i + 6].tolist()))
                    self.rejected_bytes += i - pos
                    pos = i + FRAME_LENGTH
        # keep the first sync byte too close to the end to hold a whole frame; reject everything before it
        tail = max(pos, n - FRAME_LENGTH + 1)
        syncs = np.flatnonzero(buf[tail:] == SYNC)
        keep = tail + int(syncs[0]) if syncs.size else n
        self.rejected_bytes += keep - pos
        del self._buffer[:keep]
        return frames

    def encode(self, frame: Frame) -> bytes:
        return frame.to_bytes()

    def clear(self) -> None:
        self._buffer.clear()


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
        # A head keeps its pose over a reconnect, so a query is simply asked again (no on_reconnect).
        self.link = SerialLink(url, PelcoDFramer(), f"pan/tilt head (address {address})", timeout_s=timeout_s,
                               baudrate=baudrate, reconnect_attempts=retries + 1,
                               hint="check the head's power and cable, the port (e.g. /dev/ttyUSB0) or "
                                    "socket:// address, the baud rate and the head's Pelco-D address, or pass --sim")
        self.link.open()
        self._resends = 0
        self.commanded: tuple[float, float] | None = None

    @property
    def reconnects(self) -> int:
        return self.link.reconnects

    @property
    def retries_used(self) -> int:
        """How many resends were needed so far (queries asked again, set commands sent again): diagnostics."""
        return self.link.faults_recovered + self._resends

    # -- context manager -------------------------------------------------------------------------------
    def __enter__(self) -> PanTiltHead:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def close(self) -> None:
        self.link.close()

    # -- protocol --------------------------------------------------------------------------------------
    def _query(self, query_command: int) -> float:
        reply_command = REPLY_FOR_QUERY[query_command]
        name = "pan" if query_command == QUERY_PAN else "tilt"

        def answer(frame: Frame) -> float | None:
            if frame.address == self.address and frame.command2 == reply_command:
                return data_to_angle(frame.data)
            return None  # another head's frame, or a reply to another query

        return self.link.exchange(lambda: message(self.address, query_command), answer, retries=self.retries,
                                  timeout_s=self.timeout_s, what=f"the {name} query")

    # -- public API ------------------------------------------------------------------------------------
    def position(self) -> tuple[float, float]:
        """(pan, tilt) in degrees as the head reports them."""
        return self._query(QUERY_PAN), self._query(QUERY_TILT)

    def command(self, pan_deg: float, tilt_deg: float) -> None:
        """Send the absolute position without waiting."""
        with self.link.lock:
            self.link.send(message(self.address, SET_PAN, angle_to_data(pan_deg)))
            self.link.send(message(self.address, SET_TILT, angle_to_data(tilt_deg)))
        self.commanded = (data_to_angle(angle_to_data(pan_deg)), data_to_angle(angle_to_data(tilt_deg)))

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
        resend_after = time.monotonic() + RESEND_AFTER_S
        while time.monotonic() < deadline:
            if _angle_diff(last[0], target[0]) <= POSITION_TOLERANCE_DEG and \
                    _angle_diff(last[1], target[1]) <= POSITION_TOLERANCE_DEG:
                return last
            time.sleep(POLL_INTERVAL_S)
            previous, last = last, self.position()
            if last == previous and time.monotonic() > resend_after:  # not moving: the command may be lost
                self._resends += 1
                self.command(*target)
                resend_after = time.monotonic() + RESEND_AFTER_S
        raise DeviceError(
            f"pan/tilt head at {self.url} did not reach pan {target[0]:.2f}°, tilt {target[1]:.2f}° within "
            f"{self.settle_timeout_s:.1f} s (it reports pan {last[0]:.2f}°, tilt {last[1]:.2f}°)",
            "check that nothing blocks the head and that its limits allow this position")


def _angle_diff(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)

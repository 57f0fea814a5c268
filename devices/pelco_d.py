"""Pelco-D framing and the absolute-positioning commands of a pan/tilt head (no transport here).

A Pelco-D message is 7 bytes:  0xFF, address, command1, command2, data1, data2, checksum
where checksum = (address + command1 + command2 + data1 + data2) mod 256. Absolute positioning
(the "extended" command set most heads implement):

    set pan position   cmd2 0x4B   data = pan  in hundredths of a degree, 0 … 35999
    set tilt position  cmd2 0x4D   data = tilt in hundredths of a degree, negative tilt as 36000 + tilt
    query pan          cmd2 0x51   → reply cmd2 0x59 with the pan position in data
    query tilt         cmd2 0x53   → reply cmd2 0x5B with the tilt position in data

Angles therefore have a resolution of 0.01°. Heads differ in whether they acknowledge set commands; this
driver does not rely on it: it confirms a move by querying the position.
"""

from __future__ import annotations

from dataclasses import dataclass

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


def checksum(body: bytes) -> int:
    """Pelco-D checksum of the 5 bytes after the sync byte."""
    return sum(body) & 0xFF


def encode(address: int, command2: int, data: int = 0, command1: int = 0) -> bytes:
    """The 7 bytes of a message; data is a 16-bit value (data1 = high byte)."""
    if not 0 <= address <= 255:
        raise ValueError(f"Pelco-D address must be 0…255, got {address}")
    if not 0 <= data <= 0xFFFF:
        raise ValueError(f"Pelco-D data must be 0…65535, got {data}")
    body = bytes([address, command1, command2, (data >> 8) & 0xFF, data & 0xFF])
    return bytes([SYNC]) + body + bytes([checksum(body)])


def angle_to_data(angle_deg: float) -> int:
    """An angle in degrees (any sign) as Pelco-D hundredths of a degree in 0 … 35999."""
    return round(angle_deg * 100.0) % CENTIDEGREES_PER_TURN


def data_to_angle(data: int, signed: bool = True) -> float:
    """Pelco-D hundredths of a degree back to degrees; signed maps 180° … 360° to -180° … 0°."""
    centi = data % CENTIDEGREES_PER_TURN
    if signed and centi >= CENTIDEGREES_PER_TURN // 2:
        centi -= CENTIDEGREES_PER_TURN
    return centi / 100.0


class FrameDecoder:
    """Turns a byte stream into frames: resynchronises on 0xFF and drops bytes whose checksum fails.

    Garbage, truncated frames and corrupted bytes are counted in `rejected_bytes`, never raised: the caller
    decides by timeout whether an answer came.
    """

    def __init__(self) -> None:
        self._buffer = bytearray()
        self.rejected_bytes = 0

    def feed(self, data: bytes) -> list[Frame]:
        self._buffer.extend(data)
        frames: list[Frame] = []
        while True:
            start = self._buffer.find(SYNC)
            if start < 0:
                self.rejected_bytes += len(self._buffer)
                self._buffer.clear()
                break
            if start > 0:
                self.rejected_bytes += start
                del self._buffer[:start]
            if len(self._buffer) < FRAME_LENGTH:
                break
            body = bytes(self._buffer[1:6])
            if checksum(body) == self._buffer[6]:
                frames.append(Frame(*body))
                del self._buffer[:FRAME_LENGTH]
            else:  # not a frame start after all (or corrupted): skip this sync byte and look again
                self.rejected_bytes += 1
                del self._buffer[:1]
        return frames

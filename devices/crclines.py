"""CRC lines with request ids: the framing and request loop the wall scanner, the 2-D laser and the robot base
share (each protocol's commands are in its own module: devices/wallscanner.py, laser2d.py, robotbase.py).

Every line in both directions ends with `*CCCCCCCC`: the CRC-32 (zlib/IEEE) of all bytes before the `*`, eight
upper-case hex digits (an NMEA-style XOR byte lets ~1/256 damaged lines through, and insertions of equal byte
pairs always: too weak for "never a silently wrong sample").
Requests start with `#<id> ` (id 1..65535, chosen by the host) and every response line repeats it, so a late
answer to an earlier request can never be taken for the current one. Errors are `#<id> ERR <code> <text>`:
1 unknown command, 2 bad checksum (the request arrived damaged: sent again), 3 state lost (no buffer, not
armed: the host redoes its step), 4 bad argument; other codes are the device's own.

`TaggedClient.fetch_indexed` reads a device's buffer in chunks of indexed lines (`GET <first> <count>`, answered
by lines that name their indices and `END <count>`), fetching again whatever a damaged line lost.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np

from devices.errors import DeviceError, DeviceRefusedError, DeviceResetError, RequestDamagedError
from devices.link import LineFramer, SerialLink

LINE_BITS = 64 * 10  # the longest answer line (an S line is under 64 bytes) on the wire, 10 bits a byte


def checksum(body: str) -> str:
    return f"{zlib.crc32(body.encode('ascii', errors='replace')):08X}"


def frame_line(body: str) -> str:
    return f"{body}*{checksum(body)}"


def unframe_line(line: str) -> str | None:
    """The body of a line whose checksum is right, else None."""
    star = line.rfind("*")
    if star < 0 or len(line) - star != 9:
        return None
    body = line[:star]
    return body if line[star + 1:].upper() == checksum(body) else None


@dataclass(frozen=True)
class Damaged:
    """A line whose checksum is wrong (garbled, truncated, noise), as it arrived: a device answers it with
    ERR 2 under the id it seems to carry, the host skips it."""

    text: str


class CrcLineFramer:
    """Text lines that end in `*CCCCCCCC`: feed() gives the body of every sound line and Damaged for the rest;
    encode() appends the checksum to a body."""

    terminator = LineFramer.terminator
    noise = LineFramer.noise

    def __init__(self) -> None:
        self._lines = LineFramer()

    @property
    def rejected_bytes(self) -> int:
        return self._lines.rejected_bytes

    def feed(self, data: bytes) -> list[str | Damaged]:
        return [Damaged(line) if (body := unframe_line(line)) is None else body for line in self._lines.feed(data)]

    def encode(self, frame: str) -> bytes:
        return self._lines.encode(frame_line(frame))

    def clear(self) -> None:
        self._lines.clear()


# (fields of one answer line) -> (index, row values) pairs it holds; an empty iterable for lines of another shape
RowParser = Callable[[list[str]], Iterable[tuple[int, tuple[int, ...]]]]


class TaggedClient:
    """A host's side of a CRC-line protocol with request ids, over a SerialLink framed by CrcLineFramer.
    `refused` is the protocol's DeviceRefusedError for ERR codes a person must see."""

    refused: type[DeviceRefusedError] = DeviceRefusedError
    what = "device"

    def __init__(self, link: SerialLink[str | Damaged, str], retries: int = 8) -> None:
        self.link = link
        self.retries = retries
        self._next_id = 1
        self._seen_reconnects = link.reconnects
        self._protocol_faults = 0

    @property
    def faults_recovered(self) -> int:
        """Faults got over so far: the link's (timeouts, resends, reconnects) and the protocol's own."""
        return self.link.faults_recovered + self._protocol_faults

    def _new_id(self) -> int:
        value = self._next_id
        self._next_id = self._next_id % 65535 + 1
        return value

    def _check_reset(self) -> None:
        if self.link.reconnects != self._seen_reconnects:
            self._seen_reconnects = self.link.reconnects
            raise DeviceResetError(f"{self.what} reconnected")

    def _reconnected(self) -> DeviceResetError:
        self._seen_reconnects = self.link.reconnects
        return DeviceResetError(f"{self.what} reconnected")

    def request(self, command: str, multi: int = 0) -> list[list[str]]:
        """Send `command`; return the answer's fields (one list per line). multi > 0: the answer is up to that
        many lines and END, all returned; a longer one is a fault and asked again, and the try's deadline grows
        by the time those lines take on the wire."""
        tag = ""
        lines: list[list[str]] = []
        timeout_s = self.link.timeout_s + multi * LINE_BITS / self.link.baudrate

        def tagged_request() -> str:
            nonlocal tag
            tag = f"#{self._new_id()}"  # a fresh id per try: a late answer to an earlier try is ignored
            lines.clear()
            return f"{tag} {command}"

        def answer(line: str | Damaged) -> list[list[str]] | None:
            fields = line.split() if isinstance(line, str) else []
            if len(fields) < 2 or fields[0] != tag:
                self._protocol_faults += 1  # bad checksum, stale answer or noise
                return None
            if fields[1] == "ERR":
                code = int(fields[2]) if len(fields) > 2 and fields[2].isdigit() else -1
                if code == 2:  # our request arrived damaged
                    raise RequestDamagedError(f"{command!r} -> {' '.join(fields[1:])}")
                if code == 3:
                    raise DeviceResetError(f"{self.what} lost its state ({' '.join(fields[3:])})")
                raise self.refused(f"{self.what} ({self.link.url}): {command!r} -> {' '.join(fields[1:])}")
            lines.append(fields[1:])
            if len(lines) > multi + 1:  # more than asked for: a device that keeps talking, not our answer
                raise RequestDamagedError(f"{command!r} -> more than {multi} lines before END")
            return lines if not multi or fields[1] == "END" else None

        with self.link.lock:
            self._check_reset()
            return self.link.exchange(tagged_request, answer, retries=self.retries,
                                      on_reconnect=self._reconnected, timeout_s=timeout_s)

    def ok_fields(self, command: str, count: int) -> list[str]:
        """The `count` fields after OK of a one-line answer; the protocol's refusal for any other answer."""
        fields = self.request(command)[0]
        if fields[0] != "OK" or len(fields) < count + 1:
            raise self.refused(f"{self.what} ({self.link.url}): unexpected answer {' '.join(fields)!r} to "
                               f"{command!r}")
        return fields[1:count + 1]

    def fetch_indexed(self, count: int, width: int, chunk: int, parse: RowParser, rows_per_line: int = 1) -> np.ndarray:
        """Rows 0..count-1 of the device's buffer, (count, width) int64, by `GET <first> <chunk>` requests whose
        answers hold rows_per_line rows a line; rows a damaged line lost are fetched again (DeviceError when
        `retries` requests bring nothing new)."""
        rows = np.zeros((count, width), dtype=np.int64)
        have = np.zeros(count, dtype=bool)
        failures = 0
        while failures <= self.retries:
            missing = np.flatnonzero(~have)
            if missing.size == 0:
                return rows
            before = int(have.sum())
            first = int(missing[0])
            size = min(chunk, count - first)
            lines = -(-size // rows_per_line)  # the answer's length bounds the request's deadline
            for fields in self.request(f"GET {first} {size}", multi=lines):
                try:
                    parsed = list(parse(fields))
                except ValueError:
                    self._protocol_faults += 1
                    continue
                for k, values in parsed:
                    if first <= k < first + size and len(values) == width:
                        rows[k] = values
                        have[k] = True
            if int(have.sum()) == before:
                failures += 1
        raise DeviceError(f"{self.what} at {self.link.url}: rows {np.flatnonzero(~have)[:5].tolist()}… could not be "
                          "read", "check the connection and resume")

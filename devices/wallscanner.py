"""The wall scanner's line protocol (ours, documented here; the simulator in scanner/sim/devices.py speaks it):
its framing (`CrcLineFramer`) and the host's driver (`WallScanner`).

Every line in both directions ends with `*CCCCCCCC`: the CRC-32 (zlib/IEEE) of all bytes before the `*`, eight
upper-case hex digits (an NMEA-style XOR byte lets ~1/256 damaged lines through, and insertions of equal byte
pairs always: too weak for "never a silently wrong sample").
Requests start with `#<id> ` (id 1..65535, chosen by the host) and every response line repeats it, so a late
answer to an earlier request can never be taken for the current one.

    host -> device                       device -> host
    #7 ID?*CRC                            #7 OK WALLSCAN <model> <firmware>*CRC
    #8 CLK?*CRC                           #8 OK <t_us>*CRC              device clock, microseconds
    #9 ARM <rate_hz> <tag>*CRC            #9 OK <t_us>*CRC              sampling starts at t_us: sample k is
                                                                     taken at t_us + k * round(1e6 / rate_hz)
    #10 DISARM*CRC                        #10 OK <n>*CRC                n samples are buffered
    #11 GET <first> <count>*CRC           #11 S <k> <t_us> <ind> <cap> <ac>*CRC   (one line per sample)
                                         #11 END <count>*CRC
    errors                               #<id> ERR <code> <text>*CRC   1 unknown command, 2 bad checksum,
                                                                     3 not armed / no buffer, 4 bad argument
Readings are device counts 0..1000 (display units × 1000); <tag> is echoed nowhere but lets a simulator
reproduce a pass. After a power cycle or reconnect the buffer is gone (`ERR 3`): the host redoes the pass.

Robustness: a line with a bad checksum, a wrong id or a wrong shape is skipped; a request without a valid
answer before the deadline is repeated (every request is idempotent; GET is a pure read); missing or
duplicated samples in a GET are fetched again; a reading outside 0..1000 in a line with a valid checksum is
the device's own statement and is reported, not retried away.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np

from devices.errors import DeviceError, DeviceRefusedError, DeviceResetError, RequestDamagedError
from devices.link import LineFramer, SerialLink

GET_CHUNK = 200
COUNTS_MAX = 1000
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


class ScannerError(DeviceRefusedError):
    """The wall scanner refused a request or reported impossible values."""


class WallScanner:
    """Client of the wall scanner over a SerialLink framed by CrcLineFramer."""

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
            raise DeviceResetError("scanner reconnected")

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
                    raise DeviceResetError("scanner lost its buffer")
                raise ScannerError(f"scanner ({self.link.url}): {command!r} -> {' '.join(fields[1:])}")
            lines.append(fields[1:])
            if len(lines) > multi + 1:  # more than asked for: a device that keeps talking, not our answer
                raise RequestDamagedError(f"{command!r} -> more than {multi} lines before END")
            return lines if not multi or fields[1] == "END" else None

        with self.link.lock:
            self._check_reset()
            return self.link.exchange(tagged_request, answer, retries=self.retries,
                                      on_reconnect=self._reconnected, timeout_s=timeout_s)

    def _reconnected(self) -> DeviceResetError:
        self._seen_reconnects = self.link.reconnects
        return DeviceResetError("scanner reconnected")

    def _ok_value(self, command: str) -> str:
        fields = self.request(command)[0]
        if fields[0] != "OK" or len(fields) < 2:
            raise ScannerError(f"scanner ({self.link.url}): unexpected answer {' '.join(fields)!r} to {command!r}")
        return fields[1]

    def identify(self) -> str:
        return " ".join(self.request("ID?")[0][1:])

    def clock_us(self) -> int:
        return int(self._ok_value("CLK?"))

    def arm(self, rate_hz: float, tag: int) -> int:
        """Start sampling; returns the device time (µs) of sample 0."""
        return int(self._ok_value(f"ARM {rate_hz:g} {int(tag)}"))

    def disarm(self) -> int:
        """Stop sampling; returns the number of samples buffered."""
        return int(self._ok_value("DISARM"))

    def fetch(self, count: int) -> tuple[np.ndarray, np.ndarray]:
        """Samples 0..count-1 of the buffer: (t_us (n,) int64, counts (n, 3) int64). Missing ones re-fetched."""
        t_us = np.full(count, -1, dtype=np.int64)
        readings = np.zeros((count, 3), dtype=np.int64)
        have = np.zeros(count, dtype=bool)
        failures = 0
        while failures <= self.retries:
            missing = np.flatnonzero(~have)
            if missing.size == 0:
                return t_us, readings
            before = int(have.sum())
            first = int(missing[0])
            chunk = min(GET_CHUNK, count - first)
            for fields in self.request(f"GET {first} {chunk}", multi=chunk):
                if fields[0] != "S" or len(fields) != 6:
                    continue
                try:
                    k, t, a, b, c = (int(v) for v in fields[1:])
                except ValueError:
                    self._protocol_faults += 1
                    continue
                if not first <= k < first + chunk:
                    continue
                for name, value in (("inductive", a), ("capacitive", b), ("ac", c)):
                    if not 0 <= value <= COUNTS_MAX:
                        raise ScannerError(f"scanner ({self.link.url}) reported {name} = {value} counts in sample "
                                           f"{k}, outside 0..{COUNTS_MAX}",
                                           "the sensor may be faulty or saturated by metal at the device; "
                                           "check it and resume")
                t_us[k], readings[k] = t, (a, b, c)
                have[k] = True
            if int(have.sum()) == before:
                failures += 1
        raise DeviceError(f"scanner at {self.link.url}: samples {np.flatnonzero(~have)[:5].tolist()}… could not be "
                        "read", "check the connection and resume")

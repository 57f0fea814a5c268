"""The wall scanner's line protocol (ours, summarised here, specified for firmware authors in
docs/scanner-protocol.md; the simulator in scanner/sim/devices.py speaks it, `arproj devices-check scanner URL`
checks an implementation): its framing (`CrcLineFramer`) and the host's driver (`WallScanner`).

Lines are CRC lines with request ids (devices/crclines.py, shared with the 2-D laser and the robot base):
every line ends with `*CCCCCCCC`, the CRC-32 of the bytes before the `*`; requests start with `#<id> ` and every
response line repeats it.

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

import numpy as np

from devices.crclines import CrcLineFramer, Damaged, TaggedClient, checksum, frame_line, unframe_line
from devices.errors import DeviceRefusedError
from devices.link import SerialLink

__all__ = ["COUNTS_MAX", "GET_CHUNK", "CrcLineFramer", "Damaged", "ScannerError", "WallScanner", "checksum",
           "frame_line", "unframe_line"]

GET_CHUNK = 200
COUNTS_MAX = 1000


class ScannerError(DeviceRefusedError):
    """The wall scanner refused a request or reported impossible values."""


class WallScanner(TaggedClient):
    """Client of the wall scanner over a SerialLink framed by CrcLineFramer."""

    refused = ScannerError
    what = "scanner"

    def __init__(self, link: SerialLink[str | Damaged, str], retries: int = 8) -> None:
        super().__init__(link, retries)

    def identify(self) -> str:
        return " ".join(self.request("ID?")[0][1:])

    def clock_us(self) -> int:
        return int(self.ok_fields("CLK?", 1)[0])

    def arm(self, rate_hz: float, tag: int) -> int:
        """Start sampling; returns the device time (µs) of sample 0."""
        return int(self.ok_fields(f"ARM {rate_hz:g} {int(tag)}", 1)[0])

    def disarm(self) -> int:
        """Stop sampling; returns the number of samples buffered."""
        return int(self.ok_fields("DISARM", 1)[0])

    def fetch(self, count: int) -> tuple[np.ndarray, np.ndarray]:
        """Samples 0..count-1 of the buffer: (t_us (n,) int64, counts (n, 3) int64). Missing ones re-fetched."""
        def sample(fields: list[str]) -> list[tuple[int, tuple[int, ...]]]:
            if fields[0] != "S" or len(fields) != 6:
                return []
            k, t, *readings = (int(v) for v in fields[1:])
            for name, value in zip(("inductive", "capacitive", "ac"), readings, strict=True):
                if not 0 <= value <= COUNTS_MAX:
                    raise ScannerError(f"scanner ({self.link.url}) reported {name} = {value} counts in sample "
                                       f"{k}, outside 0..{COUNTS_MAX}",
                                       "the sensor may be faulty or saturated by metal at the device; "
                                       "check it and resume")
            return [(k, (t, *readings))]

        rows = self.fetch_indexed(count, 4, GET_CHUNK, sample)
        return rows[:, 0].copy(), rows[:, 1:].copy()

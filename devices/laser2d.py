"""A 2-D laser scanner's line protocol (ours, as small as the job needs; documented here, the simulator in
scanner/sim/devices.py speaks it): CRC lines with request ids (devices/crclines.py) and the host's driver
(`Laser2D`). One device may hold several scan heads (the scanning robot has a horizontal and a vertical one),
named by one letter.

    host -> device                       device -> host
    #3 ID?*CRC                            #3 OK LASER2D <model> <firmware>*CRC
    #4 HEADS?*CRC                         #4 OK H V*CRC                       the heads it holds
    #5 SCAN <head> <tag>*CRC              #5 OK <n> <angle0_rad> <step_rad>*CRC
                                         one full turn is taken and buffered: n rays, ray k at
                                         angle0 + k * step (radians, counter-clockwise, 0 along the head's x)
    #6 GET <first> <count>*CRC            #6 R <k> <mm_k> <mm_k+1> ...*CRC    (at most 60 ranges a line)
                                         #6 END <count>*CRC
    errors                               #<id> ERR <code> <text>*CRC   1 unknown command, 2 bad checksum,
                                                                     3 no buffer, 4 bad argument (an unknown head)
Ranges are integer millimetres, 0 where no return came back (out of range, a window, glass). Angles are sent as
Python's round-trip float repr, so host and device compute the same ray angles (`ray_angles`). <tag> is echoed
nowhere but lets a simulator reproduce a scan; a real laser ignores it. SCAN is idempotent for a simulator (the
same tag gives the same scan), a fresh measurement for a real laser; GET is a pure read. After a reconnect the
buffer is gone (ERR 3): the host scans again.
"""

from __future__ import annotations

import numpy as np

from devices.crclines import CrcLineFramer, Damaged, TaggedClient
from devices.errors import DeviceRefusedError
from devices.link import SerialLink

__all__ = ["GET_CHUNK", "RANGES_PER_LINE", "CrcLineFramer", "Laser2D", "LaserError", "ranges_from_mm",
           "ranges_to_mm", "ray_angles"]

RANGES_PER_LINE = 60
GET_CHUNK = 600  # ranges per GET: ten lines


class LaserError(DeviceRefusedError):
    """The laser refused a request or reported values it cannot have."""


def ray_angles(angle0_rad: float, step_rad: float, n: int) -> np.ndarray:
    """(n,) float64 ray angles of a turn: angle0 + k·step, computed one way on both ends of the wire."""
    return angle0_rad + np.arange(n, dtype=np.float64) * step_rad


def ranges_to_mm(ranges_m: np.ndarray) -> np.ndarray:
    """Ranges (n,) metres, NaN for no return → wire integers (n,) int64, 0 for no return."""
    r = np.asarray(ranges_m, dtype=np.float64)
    return np.where(np.isfinite(r), np.round(np.nan_to_num(r) * 1000.0), 0).astype(np.int64)


def ranges_from_mm(mm: np.ndarray) -> np.ndarray:
    """Wire integers (n,) → ranges (n,) metres, NaN for no return (0)."""
    mm = np.asarray(mm, dtype=np.int64)
    return np.where(mm > 0, mm / 1000.0, np.nan)


class Laser2D(TaggedClient):
    """Client of a 2-D laser over a SerialLink framed by CrcLineFramer."""

    refused = LaserError
    what = "laser"

    def __init__(self, link: SerialLink[str | Damaged, str], retries: int = 8) -> None:
        super().__init__(link, retries)

    def identify(self) -> str:
        return " ".join(self.request("ID?")[0][1:])

    def heads(self) -> list[str]:
        fields = self.request("HEADS?")[0]
        return fields[1:] if fields[0] == "OK" else []

    def scan(self, head: str, tag: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """One turn of `head`: (angles (n,) rad, ranges (n,) m, NaN where nothing came back)."""
        n_text, a0_text, step_text = self.ok_fields(f"SCAN {head} {int(tag)}", 3)
        try:
            n, angle0, step = int(n_text), float(a0_text), float(step_text)
        except ValueError:
            raise LaserError(f"laser ({self.link.url}): SCAN {head} -> {n_text} {a0_text} {step_text}: not a ray "
                             "count and two angles") from None
        if not 0 < n <= 100000 or not 0 < step < 1.0:
            raise LaserError(f"laser ({self.link.url}): SCAN {head} -> {n} rays of {step} rad: impossible")

        def ranges(fields: list[str]) -> list[tuple[int, tuple[int, ...]]]:
            if fields[0] != "R" or len(fields) < 3:
                return []
            k = int(fields[1])
            values = [int(v) for v in fields[2:]]
            if any(v < 0 for v in values):
                raise LaserError(f"laser ({self.link.url}) reported a negative range in rays {k}..")
            return [(k + i, (v,)) for i, v in enumerate(values)]

        mm = self.fetch_indexed(n, 1, GET_CHUNK, ranges, rows_per_line=RANGES_PER_LINE)[:, 0]
        return ray_angles(angle0, step, n), ranges_from_mm(mm)

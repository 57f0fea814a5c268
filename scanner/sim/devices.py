"""Simulators of the GRBL drives and the wall scanner: SimDevices served by devices.sim.DeviceServer as
`socket://127.0.0.1:PORT` serial URLs, with devices.sim's fault injector.

Each speaks its device's protocol (devices/grbl.py, devices/wallscanner.py) so the host code is the same as
with real hardware. Both share a SimWorld: the GRBL simulator executes moves on the world's virtual clock
(integer microseconds; queued motion runs when the host waits with `G4 P0`), the scanner simulator samples the
sensor model along the recorded motion. After a reconnect (a fault, or a new host) GRBL is in alarm until
homed and the scanner's buffer is gone.
"""

from __future__ import annotations

import numpy as np

from devices.link import LineFramer
from devices.sim.server import SimDevice
from devices.wallscanner import CrcLineFramer, Damaged
from scanner.plan import move_time
from scanner.sim.world import MotionSegment, SimWorld

GRBL_STREAM, SCANNER_STREAM = 1, 2  # fault streams of the two simulators (the head's is 3)


class GrblSim(SimDevice):
    """GRBL 1.1 subset on the world's virtual clock (see devices/grbl.py for the dialect)."""

    name = "grbl"
    framer = LineFramer

    def __init__(self, world: SimWorld) -> None:
        self.world = world
        self.position = np.zeros(2)  # metres
        self.pending: list[tuple[np.ndarray, float]] = []
        self.state = "Alarm"
        self.feed = 0.0
        self.absolute = True

    def greeting(self) -> list[str]:
        return ["", "Grbl 1.1h ['$' for help]", "[MSG:'$H'|'$X' to unlock]"]

    def reset(self) -> None:
        self.pending.clear()
        self.state = "Alarm"

    def _run_pending(self) -> None:
        d = self.world.drives
        for target, speed in self.pending:
            length = float(np.linalg.norm(target - self.position))
            if length < 1e-9:  # GRBL's planner drops zero-length blocks (e.g. a repeated absolute move)
                continue
            duration_us = round(move_time(length, speed, d.accel_m_s2) * 1e6)
            self.world.record_motion(MotionSegment(self.world.clock_us, duration_us, self.position.copy(),
                                                   target.copy(), speed))
            self.world.clock_us += duration_us
            self.position = target
        self.pending.clear()

    def handle(self, line: str) -> list[str]:
        d = self.world.drives
        line = line.strip()
        if line == "?":
            state = "Run" if self.pending else self.state
            u, v = self.position * 1000.0
            return [f"<{state}|MPos:{u:.3f},{v:.3f},0.000|FS:{self.feed:.0f},0>"]
        if line == "$H":
            self.pending.clear()
            self.pending.append((np.zeros(2), d.rapid_speed_m_s))
            self._run_pending()
            self.state = "Idle"
            return ["ok"]
        if line == "$X":
            self.state = "Idle"
            return ["[MSG:Caution: Unlocked]", "ok"]
        words = line.upper().split()
        if not words or any(len(w) < 2 or not w[0].isalpha() for w in words):
            return ["error:1"]
        try:
            values = {w[0]: float(w[1:]) for w in words}
        except ValueError:
            return ["error:2"]
        if self.state == "Alarm":
            return ["error:9"]
        codes = [w for w in words if w[0] == "G"]
        target = self.pending[-1][0].copy() if self.pending else self.position.copy()
        motion = None
        for code in codes:
            number = float(code[1:])
            if number in (0.0, 1.0):
                motion = int(number)
            elif number == 4.0:
                self._run_pending()
                return ["ok"]
            elif number == 21.0:
                pass
            elif number == 90.0:
                self.absolute = True
            else:
                return ["error:20"]
        if "F" in values:
            self.feed = values["F"]
        if motion is None:
            return ["ok"]
        if "X" in values:
            target[0] = values["X"] / 1000.0
        if "Y" in values:
            target[1] = values["Y"] / 1000.0
        if not (-1e-9 <= target[0] <= d.travel_u_m + 1e-9 and -1e-9 <= target[1] <= d.travel_v_m + 1e-9):
            self.pending.clear()
            self.state = "Alarm"
            return ["ALARM:2"]
        if motion == 1:
            if self.feed <= 0:
                return ["error:22"]
            speed = min(self.feed / 60000.0, d.rapid_speed_m_s)
        else:
            speed = d.rapid_speed_m_s
        self.pending.append((target, speed))
        return ["ok"]


class WallScannerSim(SimDevice):
    """The wall scanner's protocol (devices/wallscanner.py) over the world's sensor model."""

    name = "wallscanner"
    framer = CrcLineFramer

    def __init__(self, world: SimWorld) -> None:
        self.world = world
        self.armed_at: int | None = None
        self.period_us = 0
        self.tag = 0
        self.buffer_t: np.ndarray | None = None
        self.buffer_counts: np.ndarray | None = None

    def reset(self) -> None:
        self.armed_at = None
        self.buffer_t = self.buffer_counts = None

    def handle(self, line: str | Damaged) -> list[str]:
        if isinstance(line, Damaged):
            words = line.text.split()
            tag = words[0] if words and words[0].startswith("#") and words[0][1:].isdigit() else "#0"
            return [f"{tag} ERR 2 bad checksum"]
        words = line.split()
        if len(words) < 2 or not words[0].startswith("#"):
            return ["#0 ERR 1 unknown command"]
        tag, command, args = words[0], words[1], words[2:]
        try:
            return self._dispatch(tag, command, args)
        except (ValueError, IndexError):
            return [f"{tag} ERR 4 bad argument"]

    def _dispatch(self, tag: str, command: str, args: list[str]) -> list[str]:
        clock = self.world.clock_us
        if command == "ID?":
            return [f"{tag} OK WALLSCAN GMS120-SIM 1.0"]
        if command == "CLK?":
            return [f"{tag} OK {clock}"]
        if command == "ARM":
            rate, pass_tag = float(args[0]), int(args[1])
            if not 1 <= rate <= 10000:
                raise ValueError(rate)
            self.period_us = round(1e6 / rate)
            self.armed_at, self.tag = clock, pass_tag
            self.buffer_t = self.buffer_counts = None
            return [f"{tag} OK {clock}"]
        if command == "DISARM":
            if self.armed_at is None:
                return [f"{tag} ERR 3 not armed"] if self.buffer_t is None else \
                    [f"{tag} OK {len(self.buffer_t)}"]
            n = (clock - self.armed_at) // self.period_us + 1
            times = self.armed_at + np.arange(n, dtype=np.int64) * self.period_us
            self.buffer_t = times
            self.buffer_counts = self.world.sample_timeline(times, self.tag)
            self.armed_at = None
            return [f"{tag} OK {n}"]
        if command == "GET":
            if self.buffer_t is None:
                return [f"{tag} ERR 3 no buffer"]
            first, count = int(args[0]), int(args[1])
            last = min(len(self.buffer_t), first + count)
            lines = []
            for k in range(first, last):
                a, b, c = self.buffer_counts[k]  # type: ignore[index]
                lines.append(f"{tag} S {k} {self.buffer_t[k]} {a} {b} {c}")
            lines.append(f"{tag} END {max(0, last - first)}")
            return lines
        return [f"{tag} ERR 1 unknown command"]

"""Simulators of the GRBL drives and the wall scanner, served as `socket://127.0.0.1:PORT` serial URLs.

Each simulator is a TCP server thread that speaks its device's line protocol (scanner/grbl.py,
scanner/wallscanner.py) so the host code is the same as with real hardware. Both share a SimWorld: the GRBL
simulator executes moves on the world's virtual clock (integer microseconds; queued motion runs when the host
waits with `G4 P0`), the scanner simulator samples the sensor model along the recorded motion.

Fault injection (seeded, per output line): garbage bytes inside a line, a junk line, a truncated line, a
dropped line (the host times out), or the device disappearing (connection closed, refused for a while, then
back after a reset: GRBL in alarm until homed, the scanner's buffer gone). Counters say what was injected.
"""

from __future__ import annotations

import socket
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from scanner.plan import move_time
from scanner.sim.world import MotionSegment, SimWorld
from scanner.wallscanner import frame_line, unframe_line

FAULT_KINDS = ("garbage", "junk_line", "truncate", "drop", "disconnect")


@dataclass
class FaultConfig:
    rate: float = 0.0  # probability that an output line is hit by a fault
    weights: dict[str, float] = field(default_factory=lambda: {
        "garbage": 0.35, "junk_line": 0.25, "truncate": 0.25, "drop": 0.12, "disconnect": 0.03})
    down_s: float = 0.03  # how long a vanished device refuses connections
    seed: int = 0


class FaultInjector:
    def __init__(self, config: FaultConfig, stream: int) -> None:
        self.config = config
        self.rng = np.random.default_rng([config.seed, stream, 99])
        kinds = [k for k in FAULT_KINDS if config.weights.get(k, 0) > 0]
        self.kinds = kinds
        weights = np.array([config.weights[k] for k in kinds], dtype=float)
        self.p = weights / weights.sum() if len(kinds) else weights
        self.counts: Counter[str] = Counter()

    def pick(self, allow_disconnect: bool = True) -> str | None:
        """A fault for the next output line, or None. Disconnects only before an answer's first line (the
        device vanishes between exchanges, not inside one of its own bulk transfers)."""
        if self.config.rate <= 0 or self.rng.random() >= self.config.rate:
            return None
        kind = str(self.rng.choice(self.kinds, p=self.p))
        if kind == "disconnect" and not allow_disconnect:
            kind = "garbage"
        self.counts[kind] += 1
        return kind

    def garble(self, line: bytes) -> bytes:
        junk = bytes(self.rng.integers(33, 127, int(self.rng.integers(1, 6))).astype(np.uint8))
        at = int(self.rng.integers(0, len(line) + 1))
        return line[:at] + junk + line[at:]

    def junk(self) -> bytes:
        return bytes(self.rng.integers(32, 127, int(self.rng.integers(1, 30))).astype(np.uint8))

    def truncate(self, line: bytes) -> bytes:
        return line[: int(self.rng.integers(0, max(1, len(line))))]


class DeviceServer(threading.Thread):
    """A TCP server for one simulated device, one connection at a time."""

    def __init__(self, device: SimDevice, faults: FaultConfig | None = None, stream: int = 0) -> None:
        super().__init__(daemon=True, name=f"sim-{device.name}")
        self.device = device
        self.faults = FaultInjector(faults or FaultConfig(), stream)
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.listener.settimeout(0.05)
        self.port = self.listener.getsockname()[1]
        self.stopping = threading.Event()
        self.down_until = 0.0
        self.connections = 0

    @property
    def url(self) -> str:
        return f"socket://127.0.0.1:{self.port}"

    def stop(self) -> None:
        self.stopping.set()
        self.join(timeout=2.0)
        self.listener.close()

    def __enter__(self) -> DeviceServer:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def run(self) -> None:
        while not self.stopping.is_set():
            try:
                conn, _ = self.listener.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            if time.monotonic() < self.down_until:
                conn.close()  # the device is gone for now
                continue
            self.connections += 1
            self.device.reset()
            with conn:
                self._serve(conn)

    def _serve(self, conn: socket.socket) -> None:
        conn.settimeout(0.05)
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        greeting = self.device.greeting()
        if greeting:
            conn.sendall(b"".join(line.encode() + b"\n" for line in greeting))
        buffer = b""
        while not self.stopping.is_set():
            try:
                chunk = conn.recv(65536)
            except TimeoutError:
                continue
            except OSError:
                return
            if not chunk:
                return
            buffer += chunk
            while b"\n" in buffer:
                raw, buffer = buffer.split(b"\n", 1)
                out = bytearray()
                for index, line in enumerate(self.device.handle(raw.decode("ascii", errors="replace").strip())):
                    data = line.encode()
                    fault = self.faults.pick(allow_disconnect=index == 0)
                    if fault == "disconnect":
                        self.down_until = time.monotonic() + self.faults.config.down_s
                        if out:
                            conn.sendall(bytes(out))
                        conn.shutdown(socket.SHUT_RDWR)
                        return
                    if fault == "drop":
                        continue
                    if fault == "garbage":
                        data = self.faults.garble(data)
                    elif fault == "truncate":
                        data = self.faults.truncate(data)
                    elif fault == "junk_line":
                        out += self.faults.junk() + b"\n"
                    out += data + b"\n"
                try:
                    conn.sendall(bytes(out))
                except OSError:
                    return


class SimDevice(Protocol):
    """What a DeviceServer serves: a greeting on connect, a reset on (re)connect, one answer per line."""

    name: str

    def greeting(self) -> list[str]: ...

    def reset(self) -> None: ...

    def handle(self, line: str) -> list[str]: ...


class GrblSim(SimDevice):
    """GRBL 1.1 subset on the world's virtual clock (see scanner/grbl.py for the dialect)."""

    name = "grbl"

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
    """The wall scanner's protocol (scanner/wallscanner.py) over the world's sensor model."""

    name = "wallscanner"

    def greeting(self) -> list[str]:
        return []

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

    def handle(self, line: str) -> list[str]:
        body = unframe_line(line)
        if body is None:
            words = line.split()
            tag = words[0] if words and words[0].startswith("#") and words[0][1:].isdigit() else "#0"
            return [frame_line(f"{tag} ERR 2 bad checksum")]
        words = body.split()
        if len(words) < 2 or not words[0].startswith("#"):
            return [frame_line("#0 ERR 1 unknown command")]
        tag, command, args = words[0], words[1], words[2:]
        try:
            return self._dispatch(tag, command, args)
        except (ValueError, IndexError):
            return [frame_line(f"{tag} ERR 4 bad argument")]

    def _dispatch(self, tag: str, command: str, args: list[str]) -> list[str]:
        clock = self.world.clock_us
        if command == "ID?":
            return [frame_line(f"{tag} OK WALLSCAN GMS120-SIM 1.0")]
        if command == "CLK?":
            return [frame_line(f"{tag} OK {clock}")]
        if command == "ARM":
            rate, pass_tag = float(args[0]), int(args[1])
            if not 1 <= rate <= 10000:
                raise ValueError(rate)
            self.period_us = round(1e6 / rate)
            self.armed_at, self.tag = clock, pass_tag
            self.buffer_t = self.buffer_counts = None
            return [frame_line(f"{tag} OK {clock}")]
        if command == "DISARM":
            if self.armed_at is None:
                return [frame_line(f"{tag} ERR 3 not armed")] if self.buffer_t is None else \
                    [frame_line(f"{tag} OK {len(self.buffer_t)}")]
            n = (clock - self.armed_at) // self.period_us + 1
            times = self.armed_at + np.arange(n, dtype=np.int64) * self.period_us
            self.buffer_t = times
            self.buffer_counts = self.world.sample_timeline(times, self.tag)
            self.armed_at = None
            return [frame_line(f"{tag} OK {n}")]
        if command == "GET":
            if self.buffer_t is None:
                return [frame_line(f"{tag} ERR 3 no buffer")]
            first, count = int(args[0]), int(args[1])
            last = min(len(self.buffer_t), first + count)
            lines = []
            for k in range(first, last):
                a, b, c = self.buffer_counts[k]  # type: ignore[index]
                lines.append(frame_line(f"{tag} S {k} {self.buffer_t[k]} {a} {b} {c}"))
            lines.append(frame_line(f"{tag} END {max(0, last - first)}"))
            return lines
        return [frame_line(f"{tag} ERR 1 unknown command")]

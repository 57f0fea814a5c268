"""Simulators of the scanning robot's devices — GRBL drives, wall scanner, robot base, 2-D laser — as SimDevices
served by devices.sim.DeviceServer on `socket://127.0.0.1:PORT` serial URLs, with devices.sim's fault injector.

Each speaks its device's protocol (devices/grbl.py, wallscanner.py, robotbase.py, laser2d.py) so the host code
is the same as with real hardware. All share a SimWorld: the robot base simulator places the robot where the
simulated platform stops (SimRobot.stop), the laser simulator scans the room from there, the GRBL simulator
executes moves on the world's virtual clock (integer microseconds; queued motion runs when the host waits with
`G4 P0`), the scanner simulator samples the sensor model along the recorded motion. After a reconnect (a fault,
or a new host) GRBL is in alarm until homed and the scanner's and the laser's buffers are gone.
`SiteServers` serves all four.
"""

from __future__ import annotations

import math
from abc import abstractmethod

import numpy as np

from devices.laser2d import RANGES_PER_LINE, ranges_to_mm
from devices.link import LineFramer
from devices.robotbase import covariance_fields
from devices.sim import DeviceServer, FaultConfig
from devices.sim.server import SimDevice
from devices.sim.tagged import TaggedLineSim
from scanner.laser import HEADS, LaserConfig, simulated_head_scan
from scanner.plan import move_time
from scanner.sim.world import MotionSegment, RobotStop, SimRobot, SimWorld

# fault streams of the simulators (the pan/tilt head's is 3, devices/sim/pelco_d.py)
GRBL_STREAM, SCANNER_STREAM, BASE_STREAM, LASER_STREAM = 1, 2, 4, 5


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

    def chatter(self, answer: str) -> str:
        """GRBL keeps talking in status reports (as while homing): the one unsolicited frame it has."""
        return self.handle("?")[0]

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


class WallScannerSim(TaggedLineSim):
    """The wall scanner's protocol (devices/wallscanner.py) over the world's sensor model."""

    name = "wallscanner"

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

    def dispatch(self, tag: str, command: str, args: list[str]) -> list[str]:
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


class RobotBaseSim(TaggedLineSim):
    """The robot base's protocol (devices/robotbase.py): GOTO stops the simulated platform where SimRobot.stop
    says for that frame tag and places the world's robot there; POSE? reports its localization, TRUE? the truth.
    The base keeps its place across a reconnect (it does not move when its cable is replugged); a resent GOTO
    stops where the first did (the stop is a function of the frame tag)."""

    name = "robot base"

    def __init__(self, world: SimWorld, robot: SimRobot) -> None:
        self.world = world
        self.robot = robot
        self.stopped: RobotStop | None = None

    def dispatch(self, tag: str, command: str, args: list[str]) -> list[str]:
        if command == "ID?":
            return [f"{tag} OK ROBOTBASE SIM 1.0"]
        if command == "GOTO":
            x, y, phi, frame = float(args[0]), float(args[1]), float(args[2]), int(args[3])
            if not all(math.isfinite(v) for v in (x, y, phi)):
                raise ValueError(args)
            self.stopped = self.robot.stop(frame, (x, y, phi))
            self.world.place_robot(self.stopped.true, self.stopped.alignment)
            return [f"{tag} OK"]
        if command == "STATE?":
            return [f"{tag} OK IDLE"]  # the virtual clock: a move is over when it is commanded
        if command == "POSE?":
            if self.stopped is None:
                return [f"{tag} OK 0.0 0.0 0.0 {' '.join(covariance_fields(np.zeros((3, 3))))}"]
            pose = " ".join(repr(float(v)) for v in self.stopped.estimate)
            return [f"{tag} OK {pose} {' '.join(covariance_fields(self.stopped.cov))}"]
        if command == "TRUE?":
            return [f"{tag} OK {' '.join(repr(float(v)) for v in self.world.true_pose)}"]
        return [f"{tag} ERR 1 unknown command"]


class BufferedLaserSim(TaggedLineSim):
    """The 2-D laser's protocol (devices/laser2d.py) over a scan buffer: subclasses say which heads there are and
    take a turn (`take`); ID?, HEADS?, SCAN and GET are answered alike for every simulated laser."""

    name = "laser"
    model = "SIM 1.0"

    def __init__(self) -> None:
        self.buffer: np.ndarray | None = None

    def reset(self) -> None:
        self.buffer = None

    @property
    def heads(self) -> tuple[str, ...]:
        return HEADS

    @abstractmethod
    def take(self, head: str, tag: int) -> tuple[np.ndarray, float, float]:
        """One turn of `head`: (ranges (n,) metres, NaN: no return; angle of ray 0, the step; radians)."""

    def dispatch(self, tag: str, command: str, args: list[str]) -> list[str]:
        if command == "ID?":
            return [f"{tag} OK LASER2D {self.model}"]
        if command == "HEADS?":
            return [f"{tag} OK {' '.join(self.heads)}"]
        if command == "SCAN":
            head, frame = args[0], int(args[1])
            if head not in self.heads:
                return [f"{tag} ERR 4 no head {head}"]
            ranges, angle0, step = self.take(head, frame)
            self.buffer = ranges_to_mm(ranges)
            return [f"{tag} OK {len(ranges)} {float(angle0)!r} {float(step)!r}"]
        if command == "GET":
            if self.buffer is None:
                return [f"{tag} ERR 3 no buffer"]
            first, count = int(args[0]), int(args[1])
            if first < 0 or count < 0:
                raise ValueError(args)
            last = min(len(self.buffer), first + count)
            lines = [f"{tag} R {k} {' '.join(str(int(v)) for v in self.buffer[k:min(last, k + RANGES_PER_LINE)])}"
                     for k in range(first, last, RANGES_PER_LINE)]
            return [*lines, f"{tag} END {max(0, last - first)}"]
        return [f"{tag} ERR 1 unknown command"]


class LaserSim(BufferedLaserSim):
    """The scanning robot's 2-D laser with its two heads, scanning the simulated room from where the world's
    robot stands (scanner.laser.simulated_head_scan)."""

    def __init__(self, world: SimWorld, laser: LaserConfig) -> None:
        super().__init__()
        self.world = world
        self.laser = laser

    def take(self, head: str, tag: int) -> tuple[np.ndarray, float, float]:
        with self.world.lock:
            pose, alignment = self.world.true_pose, self.world.alignment
        angles, ranges = simulated_head_scan(head, pose, alignment, self.world.wall.width_m, self.laser,
                                             self.world.seed, tag)
        return ranges, float(angles[0]), self.laser.angular_step_rad


class SiteServers:
    """The scanning robot's four simulators on one SimWorld, each on its own DeviceServer (socket:// on
    127.0.0.1) with its own fault stream; `urls` names them as `arproj scan` takes them."""

    def __init__(self, world: SimWorld, robot: SimRobot, faults: FaultConfig | None = None) -> None:
        self.servers: dict[str, DeviceServer] = {
            "drives": DeviceServer(GrblSim(world), faults, stream=GRBL_STREAM),
            "scanner": DeviceServer(WallScannerSim(world), faults, stream=SCANNER_STREAM),
            "base": DeviceServer(RobotBaseSim(world, robot), faults, stream=BASE_STREAM),
            "laser": DeviceServer(LaserSim(world, robot.laser), faults, stream=LASER_STREAM),
        }
        for server in self.servers.values():
            server.start()

    @property
    def urls(self) -> dict[str, str]:
        return {name: server.url for name, server in self.servers.items()}

    @property
    def faults_injected(self) -> int:
        return sum(sum(server.faults.counts.values()) for server in self.servers.values())

    def close(self) -> None:
        for server in self.servers.values():
            server.stop()

    def __enter__(self) -> SiteServers:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

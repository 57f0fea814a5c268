"""The xy linear drives, spoken to in G-code as GRBL 1.1 speaks it.

Used subset: `$H` homing, `G21 G90` (millimetres, absolute), `G0 X Y` rapid, `G1 X Y F` feed move (mm/min),
`G4 P0` (its `ok` comes once all queued motion has finished), `?` real-time status report
`<Idle|MPos:x,y,z|FS:f,s>`, replies `ok` / `error:N`, alarms `ALARM:N`, the reset banner `Grbl 1.1h ['$' for
help]`. Drive axis X is the scanner's u, Y its v (metres in Python, millimetres on the wire). Framing: plain
text lines (`devices.link.LineFramer`).

Robustness: only absolute moves are sent, so a command whose `ok` was lost can be repeated safely; every
exchange has a deadline; garbage lines are skipped; after a reconnect (GRBL resets when its port reopens)
the drives must be homed again, which `DeviceResetError` tells the caller. Every move is verified with a status
report (Idle at the target within POSITION_TOLERANCE_MM).
"""

from __future__ import annotations

import re

from devices.errors import DeviceError, DeviceRefusedError, DeviceResetError, RequestDamagedError
from devices.link import SerialLink
from geometry.errors import InputError

POSITION_TOLERANCE_MM = 0.002
STATUS_RE = re.compile(r"^<(\w+)(?::\d+)?\|MPos:(-?\d+\.\d+),(-?\d+\.\d+),(-?\d+\.\d+)(?:\|.*)?>$")
ERROR_CODES = {
    1: "G-code words consist of a letter and a value", 2: "numeric value format is not valid",
    3: "'$' system command was not recognized", 9: "G-code locked out during alarm or jog state",
    15: "jog target exceeds machine travel", 20: "unsupported or invalid g-code command",
    22: "feed rate has not yet been set or is undefined",
}
ALARM_CODES = {1: "hard limit", 2: "soft limit: target exceeds machine travel", 3: "reset while in motion",
               8: "homing fail: pull-off", 9: "homing fail: limit switch not found"}


class GrblError(DeviceRefusedError):
    """GRBL refused a command (error:N) or raised an alarm (ALARM:N)."""


class GrblDrives:
    """Client of a GRBL controller driving the scanner's two linear axes."""

    def __init__(self, link: SerialLink[str, str], max_feed_mm_min: float = 15000.0, retries: int = 8,
                 homing_timeout_s: float = 60.0) -> None:
        self.link = link
        self.homing_timeout_s = homing_timeout_s
        self.max_feed_mm_min = max_feed_mm_min
        self.retries = retries
        self.homed = False
        self._seen_reconnects = link.reconnects
        self._protocol_faults = 0

    # ------------------------------------------------------------------ exchanges
    @property
    def faults_recovered(self) -> int:
        """Faults got over so far: the link's (timeouts, resends, reconnects) and the protocol's own."""
        return self.link.faults_recovered + self._protocol_faults

    def _exchange(self, command: str, timeout_s: float | None = None) -> str:
        """Send a command and wait for `ok` (returned as 'ok') or a status report for '?'.

        Retries on timeouts and garbled commands (the link's exchange); after a reconnect raises
        DeviceResetError, since GRBL resets when its port reopens.
        """
        def answer(line: str) -> str | None:
            line = line.strip()
            if command == "?" and STATUS_RE.match(line):
                return line
            if line == "ok" and command != "?":
                return line
            if line.startswith("error:"):
                code = _int(line[6:])
                if code in (1, 2, 20):  # our line arrived garbled
                    raise RequestDamagedError(f"{command!r} -> {line}")
                raise GrblError(f"drives ({self.link.url}): {command!r} -> {line} "
                                f"({ERROR_CODES.get(code, 'unknown error')})")
            if line.startswith("ALARM:"):
                code = _int(line[6:])
                raise GrblError(f"drives ({self.link.url}): {command!r} -> {line} ({ALARM_CODES.get(code, 'alarm')})",
                                "the drives stopped; home them ($H) and check the plan's reach")
            if line.startswith("Grbl "):  # the banner: the controller just reset
                if self.homed:  # state we relied on is gone
                    self.homed = False
                    raise DeviceResetError("drives reset")
                return None  # the greeting of a fresh connection
            self._protocol_faults += 1  # garbage or a truncated line: keep listening
            return None

        return self.link.exchange(lambda: command, answer, retries=self.retries, on_reconnect=self._reconnected,
                                  timeout_s=timeout_s)

    def _reconnected(self) -> DeviceResetError:
        self.homed = False
        return DeviceResetError("drives reconnected")

    def _check_reset(self) -> None:
        if self.link.reconnects != self._seen_reconnects:
            self._seen_reconnects = self.link.reconnects
            self.homed = False
            raise DeviceResetError("drives reconnected")

    # ------------------------------------------------------------------ commands
    def home(self) -> None:
        """`$H`, then millimetres and absolute coordinates."""
        self._exchange("$H", timeout_s=max(self.link.timeout_s, self.homing_timeout_s))
        self._exchange("G21 G90")
        self._seen_reconnects = self.link.reconnects
        self.homed = True

    def status(self) -> tuple[str, float, float]:
        """(state, u metres, v metres) from a `?` report."""
        match = STATUS_RE.match(self._exchange("?"))
        assert match is not None
        return match.group(1), float(match.group(2)) / 1000.0, float(match.group(3)) / 1000.0

    def move_to(self, u_m: float, v_m: float, speed_m_s: float | None = None) -> None:
        """Queue a move (G0 rapid when speed is None, else G1 at that feed). Returns once GRBL accepted it."""
        self._check_reset()
        if not self.homed:
            raise DeviceResetError("drives not homed")
        if speed_m_s is None:
            command = f"G0 X{u_m * 1000:.3f} Y{v_m * 1000:.3f}"
        else:
            feed = speed_m_s * 60000.0
            if not 0 < feed <= self.max_feed_mm_min:
                raise InputError(f"drives: feed {feed:.0f} mm/min (speed {speed_m_s} m/s) is outside 0.."
                                 f"{self.max_feed_mm_min:.0f} mm/min")
            command = f"G1 X{u_m * 1000:.3f} Y{v_m * 1000:.3f} F{feed:.1f}"
        self._exchange(command)

    def wait_until_at(self, u_m: float, v_m: float, expected_s: float = 0.0) -> None:
        """Wait for the motion to finish (`G4 P0`, whose ok comes when the planner is empty; the deadline is
        the expected motion time plus the link timeout) and verify Idle at the target with a status report."""
        for _ in range(self.retries + 1):
            self._exchange("G4 P0", timeout_s=1.5 * expected_s + self.link.timeout_s)
            state, u, v = self.status()
            self._check_reset()
            if state == "Idle" and abs(u - u_m) * 1000 <= POSITION_TOLERANCE_MM \
                    and abs(v - v_m) * 1000 <= POSITION_TOLERANCE_MM:
                return
            if state == "Alarm":
                self.homed = False
                raise DeviceResetError("drives in alarm")
            if state == "Idle":  # the move was lost (e.g. an ok taken for another's): redo the step
                self._protocol_faults += 1
                raise DeviceResetError("drives idle away from the target")
        raise DeviceError(f"drives at {self.link.url} did not reach u={u_m:.4f} v={v_m:.4f} m",
                        "check the drives for blocked axes or lost steps")


def _int(text: str) -> int:
    try:
        return int(text.strip())
    except ValueError:
        return -1

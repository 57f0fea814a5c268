"""A simulated Pelco-D pan/tilt head on socket://127.0.0.1:PORT (the one simulator server), with seeded faults.

It is reached exactly like the real head (PanTiltHead(sim.url)), so tests and `--sim` exercise the real
driver. The simulated head moves at a finite speed, and its physical angles can differ from what its encoder
reports (`slip_deg`: the mount slipped; the encoder does not know) — the case the session must catch with
its cameras. Faults (`HeadFaults`): dropped replies, corrupted replies, garbage bytes before a reply, slow
replies, ignored set commands (all drawn by the one fault injector), and a dead head that answers nothing.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np

from devices import pelco_d
from devices.sim.faults import FaultConfig
from devices.sim.server import DeviceServer, ServedDevice, SimDevice

HEAD_STREAM = 3  # the head's fault stream (the scanning site's simulators use 1 and 2)


@dataclass
class HeadFaults:
    """The head's faults. Rates are probabilities per reply (at most one fault per reply, so they sum to ≤ 1)
    or per set command (ignore_command_rate); `dead` and `slip_deg` are read live, so a test can change them
    while the head is connected."""

    drop_reply_rate: float = 0.0
    corrupt_reply_rate: float = 0.0
    garbage_rate: float = 0.0
    ignore_command_rate: float = 0.0
    reply_delay_s: float = 0.0
    dead: bool = False
    slip_deg: tuple[float, float] = (0.0, 0.0)  # physical minus reported (pan, tilt)

    def wire(self, seed: int) -> FaultConfig:
        """The fault injector's configuration for these faults."""
        weights = {"drop": self.drop_reply_rate, "corrupt": self.corrupt_reply_rate, "junk": self.garbage_rate}
        rate = sum(weights.values())
        if rate > 1.0 + 1e-12:
            raise ValueError(f"head fault rates sum to {rate:g} per reply: at most one fault per reply, keep it ≤ 1")
        return FaultConfig(rate=rate, weights=weights, seed=seed, ignore_rate=self.ignore_command_rate,
                           delay_s=self.reply_delay_s)


class HeadSimulator(ServedDevice, SimDevice):
    """Pelco-D head on a local TCP port, served from construction on. Use as a context manager (or close());
    `url` is what the driver opens."""

    name = "pan/tilt head"
    framer = pelco_d.PelcoDFramer

    def __init__(self, address: int = 1, speed_deg_s: float = 120.0, faults: HeadFaults | None = None,
                 seed: int = 0, initial_deg: tuple[float, float] = (0.0, 0.0)) -> None:
        self.address = address
        self.speed_deg_s = speed_deg_s
        self.faults = faults or HeadFaults()
        self._lock = threading.Lock()
        self._start = np.array(initial_deg, dtype=np.float64)
        self._target = self._start.copy()
        self._t_start = time.monotonic()
        self.server = DeviceServer(self, self.faults.wire(seed), stream=HEAD_STREAM)
        self.server.start()

    @property
    def faults_injected(self) -> int:
        return sum(self.server.faults.counts.values())

    def drop_connections(self) -> None:
        """The head vanishes for a moment (power blip, cable); a driver that reconnects gets it back."""
        self.server.drop_connection()

    # -- the simulated mechanics -----------------------------------------------------------------------
    def reported_deg(self) -> tuple[float, float]:
        """(pan, tilt) the encoder reports now (moving towards the target at speed_deg_s)."""
        with self._lock:
            pan, tilt = self._current_locked()
            return float(pan), float(tilt)

    def true_deg(self) -> tuple[float, float]:
        """(pan, tilt) the head physically has: the reported angles plus the slip."""
        pan, tilt = self.reported_deg()
        return float(pan + self.faults.slip_deg[0]), float(tilt + self.faults.slip_deg[1])

    def _current_locked(self) -> np.ndarray:
        delta = self._target - self._start
        distance = float(np.max(np.abs(delta)))
        if distance == 0.0:
            return self._target.copy()
        fraction = min(1.0, (time.monotonic() - self._t_start) * self.speed_deg_s / distance)
        return self._start + fraction * delta

    def _set_axis(self, axis: int, angle: float) -> None:
        with self._lock:
            target = self._target.copy()  # the other axis keeps moving to its own target
            target[axis] = angle
            self._start = self._current_locked()
            self._target = target
            self._t_start = time.monotonic()

    # -- the wire (a SimDevice) ------------------------------------------------------------------------
    def chatter(self, answer: pelco_d.Frame) -> pelco_d.Frame:
        """The reply of another head on the bus (the next address): a sound frame that is not ours."""
        return pelco_d.Frame((answer.address + 1) % 256, answer.command1, answer.command2, answer.data1,
                             answer.data2)

    def answers(self, frame: pelco_d.Frame) -> bool:
        return frame.command2 not in (pelco_d.SET_PAN, pelco_d.SET_TILT)

    def handle(self, frame: pelco_d.Frame) -> list[pelco_d.Frame]:
        if frame.address != self.address or self.faults.dead:
            return []
        if frame.command2 in (pelco_d.SET_PAN, pelco_d.SET_TILT):
            axis = 0 if frame.command2 == pelco_d.SET_PAN else 1
            self._set_axis(axis, pelco_d.data_to_angle(frame.data))
            return []
        if frame.command2 not in pelco_d.REPLY_FOR_QUERY:
            return []  # commands this head does not know are ignored, as real heads do
        pan, tilt = self.reported_deg()
        angle = pan if frame.command2 == pelco_d.QUERY_PAN else tilt
        return [pelco_d.message(self.address, pelco_d.REPLY_FOR_QUERY[frame.command2], pelco_d.angle_to_data(angle))]

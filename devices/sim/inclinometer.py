"""A simulated inclinometer (devices/inclinometer.py's protocol) on socket://127.0.0.1:PORT, the one simulator
server, with seeded faults.

It reads the tilt of whatever it is bolted to from a callable (the simulated site's robot: `true_tilt_deg`), so
this package needs nothing of the site. A reading is the truth plus a fixed per-device bias and fresh noise per
TILT?, both drawn from the seed; the σ it states covers them together (bias σ and noise σ are each σ/√2), as a
datasheet's accuracy does.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from devices.sim.faults import FaultConfig
from devices.sim.server import DeviceServer, ServedDevice
from devices.sim.tagged import TaggedLineSim

INCLINOMETER_STREAM = 7  # its fault stream (scanner/sim/devices.py has 1, 2, 4, 5; the head 3; the live laser 6)
SIGMA_DEG = 0.01  # the stated 1-σ per axis (a good MEMS/electrolytic two-axis sensor)


class InclinometerSim(ServedDevice, TaggedLineSim):
    """The inclinometer's protocol over true_tilt_deg() -> (roll, pitch) degrees. Served from construction on
    (`url`); close() (or `with`) stops it."""

    name = "inclinometer"

    def __init__(self, true_tilt_deg: Callable[[], tuple[float, float]], sigma_deg: float = SIGMA_DEG,
                 seed: int = 0, faults: FaultConfig | None = None) -> None:
        if not sigma_deg > 0:
            raise ValueError(f"inclinometer sigma_deg = {sigma_deg!r} must be > 0")
        self.true_tilt_deg = true_tilt_deg
        self.sigma_deg = float(sigma_deg)
        self._rng = np.random.default_rng([seed, INCLINOMETER_STREAM, 17])
        # the device's own fixed error (its zero set a little off), then fresh noise per reading
        self.bias_deg = self._rng.standard_normal(2) * self.sigma_deg / math.sqrt(2.0)
        self.server = DeviceServer(self, faults, stream=INCLINOMETER_STREAM)
        self.server.start()

    def reading_deg(self) -> tuple[float, float]:
        """One reading (roll, pitch): truth + bias + fresh noise."""
        true = np.asarray(self.true_tilt_deg(), dtype=np.float64)
        read = true + self.bias_deg + self._rng.standard_normal(2) * self.sigma_deg / math.sqrt(2.0)
        return float(read[0]), float(read[1])

    def dispatch(self, tag: str, command: str, args: list[str]) -> list[str]:
        if args:
            raise ValueError(args)  # no command of this protocol takes arguments: ERR 4
        if command == "ID?":
            return [f"{tag} OK INCLINOMETER SIM 1.0"]
        if command == "TILT?":
            roll, pitch = self.reading_deg()
            s = repr(self.sigma_deg)
            return [f"{tag} OK {roll!r} {pitch!r} {s} {s}"]
        if command == "TRUE?":
            roll, pitch = (float(v) for v in self.true_tilt_deg())
            return [f"{tag} OK {roll!r} {pitch!r}"]
        return [f"{tag} ERR 1 unknown command"]

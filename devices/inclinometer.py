"""A two-axis inclinometer's line protocol (ours, as small as the job needs; the simulator in
devices/sim/inclinometer.py speaks it): CRC lines with request ids (devices/crclines.py) and the host's driver
(`Inclinometer`).

The inclinometer is bolted to the robot's body and measures the body's tilt against gravity: its roll about the
robot's x axis (forward) and its pitch about its y axis (left), in the robot frame's own axes (REP 103: positive
roll lifts the left side, positive pitch lowers the nose; geometry.poses.tilt_rotation / roll_pitch). A device
mounted otherwise is levelled to the robot's axes in its firmware: the host takes its numbers as the body's.

    host -> device                        device -> host
    #1 ID?*CRC                            #1 OK INCLINOMETER <model> <firmware>*CRC
    #2 TILT?*CRC                          #2 OK <roll_deg> <pitch_deg> <sigma_roll_deg> <sigma_pitch_deg>*CRC
                                          one fresh reading (degrees) and its 1-σ, bias and noise together
                                          (the datasheet's accuracy: what the host may fuse it with)
    #3 TRUE?*CRC                          simulators only: #3 OK <roll_deg> <pitch_deg>*CRC, the tilt the
                                          body really has (a real inclinometer answers ERR 1)
    errors                                #<id> ERR <code> <text>*CRC   1 unknown command, 2 bad checksum,
                                                                      4 bad argument
Numbers are sent as Python's round-trip float repr. Every command is a pure read and may be resent; the
device holds no state, so a reconnect loses nothing and the host just asks again.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from devices.crclines import CrcLineFramer, Damaged, TaggedClient
from devices.errors import DeviceError, DeviceRefusedError, DeviceResetError
from devices.link import SerialLink

__all__ = ["MAX_TILT_DEG", "CrcLineFramer", "Inclinometer", "InclinometerError", "TiltReading"]

MAX_TILT_DEG = 30.0  # a robot tilted further than this is not standing: a reading beyond it is a fault


class InclinometerError(DeviceRefusedError):
    """The inclinometer refused a request or reported values it cannot have."""


@dataclass(frozen=True)
class TiltReading:
    """One reading: the body's roll and pitch against gravity and their 1-σ, degrees."""

    roll_deg: float
    pitch_deg: float
    sigma_roll_deg: float
    sigma_pitch_deg: float


class Inclinometer(TaggedClient):
    """Client of an inclinometer over a SerialLink framed by CrcLineFramer."""

    refused = InclinometerError
    what = "inclinometer"

    def __init__(self, link: SerialLink[str | Damaged, str], retries: int = 8) -> None:
        super().__init__(link, retries)

    def read(self, command: str, count: int) -> list[str]:
        """The fields after OK (at least `count`) of a one-line answer, asked again after a reconnect (a
        stateless device lost nothing); InclinometerError for any other answer."""
        for _ in range(self.retries + 1):
            try:
                fields = self.request(command)[0]
            except DeviceResetError:
                continue
            if fields[0] != "OK" or len(fields) < count + 1:
                raise InclinometerError(f"inclinometer ({self.link.url}): unexpected answer {' '.join(fields)!r} "
                                        f"to {command!r}")
            return fields[1:]
        raise DeviceError(f"inclinometer ({self.link.url}) reconnected {self.retries + 1} times in one reading",
                          "check the inclinometer's cable and power")

    def identify(self) -> str:
        return " ".join(self.read("ID?", 1))

    def tilt(self) -> TiltReading:
        """A fresh reading; InclinometerError for numbers it cannot have (not finite, beyond MAX_TILT_DEG, a σ
        that is not positive)."""
        fields = self.read("TILT?", 4)[:4]
        try:
            roll, pitch, s_roll, s_pitch = (float(v) for v in fields)
        except ValueError:
            raise InclinometerError(f"inclinometer ({self.link.url}): TILT? -> {' '.join(fields)}: not numbers"
                                    ) from None
        if not all(math.isfinite(v) for v in (roll, pitch, s_roll, s_pitch)) or \
                max(abs(roll), abs(pitch)) > MAX_TILT_DEG or not (s_roll > 0 and s_pitch > 0):
            raise InclinometerError(f"inclinometer ({self.link.url}) reported a tilt it cannot have: "
                                    f"{' '.join(fields)} (roll, pitch, σ roll, σ pitch in degrees)",
                                    "check the inclinometer's mounting and settings")
        return TiltReading(roll, pitch, s_roll, s_pitch)

    def true_tilt(self) -> tuple[float, float] | None:
        """The body's true (roll, pitch) in degrees from a simulator; None for a real inclinometer (it does
        not know TRUE?)."""
        try:
            roll, pitch = (float(v) for v in self.read("TRUE?", 2)[:2])
        except InclinometerError:
            return None
        return roll, pitch

"""Devices of the projection robot reached over pyserial URLs: the pan/tilt head (Pelco-D) and its simulator.

The protocol (framing, checksums, encoding of angles) lives apart from the transport (a pyserial URL: a real
port such as /dev/ttyUSB0, `socket://127.0.0.1:PORT` for the simulator, or `loop://`), so the simulator and
the real head share one code path.
"""

from arproj.devices.errors import DeviceError, DeviceTimeoutError
from arproj.devices.head import PanTiltHead
from arproj.devices.head_sim import HeadFaults, HeadSimulator

__all__ = ["DeviceError", "DeviceTimeoutError", "HeadFaults", "HeadSimulator", "PanTiltHead"]

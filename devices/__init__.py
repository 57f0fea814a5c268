"""Devices reached over pyserial URLs: one link, one framer per wire format, one module per protocol.

    link.py         SerialLink (a pyserial URL: a real port such as /dev/ttyUSB0, `socket://host:port`,
                    `loop://`) with exchange(), deadlines and reconnects; the Framer protocol; LineFramer
    errors.py       the one error tree (DeviceError, an InputError, and what it holds)
    grbl.py         G-code as GRBL speaks it: the xy linear drives (GrblDrives), plain lines
    wallscanner.py  the wall scanner's line protocol: CRC lines with request ids (WallScanner)
    pelco_d.py      Pelco-D: 7-byte frames, the pan/tilt head (PanTiltHead)
    sim/            the one simulator server (socket:// on 127.0.0.1), the one fault injector, the head simulator

A protocol is one module: its framer (or LineFramer), its driver over a SerialLink and its errors from
errors.py; its simulator is a SimDevice on sim.DeviceServer. This package imports nothing of the project but
geometry (for InputError).
"""

from devices.errors import (
    DeviceError,
    DeviceRefusedError,
    DeviceResetError,
    DeviceTimeoutError,
    DisconnectedError,
    FrameTimeoutError,
    RequestDamagedError,
)
from devices.grbl import GrblDrives, GrblError
from devices.link import Framer, LineFramer, SerialLink
from devices.pelco_d import PanTiltHead, PelcoDFramer
from devices.wallscanner import CrcLineFramer, ScannerError, WallScanner

__all__ = ["CrcLineFramer", "DeviceError", "DeviceRefusedError", "DeviceResetError", "DeviceTimeoutError",
           "DisconnectedError", "FrameTimeoutError", "Framer", "GrblDrives", "GrblError", "LineFramer",
           "PanTiltHead", "PelcoDFramer", "RequestDamagedError", "ScannerError", "SerialLink", "WallScanner"]

"""Devices reached over pyserial URLs: one link, one framer per wire format, one module per protocol.

    link.py         SerialLink (a pyserial URL: a real port such as /dev/ttyUSB0, `socket://host:port`,
                    `loop://`) with exchange(), deadlines and reconnects; the Framer protocol; LineFramer
    errors.py       the one error tree (DeviceError, an InputError, and what it holds)
    grbl.py         G-code as GRBL speaks it: the xy linear drives (GrblDrives), plain lines
    pelco_d.py      Pelco-D: 7-byte frames, the pan/tilt head (PanTiltHead)
    crclines.py     CRC lines with request ids: the framing and request loop of the next four
    wallscanner.py  the wall scanner's line protocol (WallScanner)
    laser2d.py      a 2-D laser's line protocol: scans of ranges and angles (Laser2D)
    robotbase.py    the scanning robot's base: go to a frame pose, report the pose with its covariance (RobotBase)
    inclinometer.py the projection robot's two-axis inclinometer: its roll and pitch against gravity (Inclinometer)
    recording.py    recorded sessions in spy://'s hexdump: record:// and replay:// URLs (urlhandler/)
    sim/            the one simulator server (socket:// on 127.0.0.1), the one fault injector, the head and
                    inclinometer simulators

A protocol is one module: its framer (or LineFramer), its driver over a SerialLink and its errors from
errors.py; its simulator is a SimDevice on sim.DeviceServer. This package imports nothing of the project but
geometry (for InputError).
"""

import serial

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
from devices.inclinometer import Inclinometer, InclinometerError
from devices.laser2d import Laser2D, LaserError
from devices.link import Framer, LineFramer, SerialLink
from devices.pelco_d import PanTiltHead, PelcoDFramer
from devices.robotbase import RobotBase, RobotBaseError
from devices.wallscanner import CrcLineFramer, ScannerError, WallScanner

if "devices.urlhandler" not in serial.protocol_handler_packages:  # record:// and replay:// URLs
    serial.protocol_handler_packages.append("devices.urlhandler")

__all__ = ["CrcLineFramer", "DeviceError", "DeviceRefusedError", "DeviceResetError", "DeviceTimeoutError",
           "DisconnectedError", "FrameTimeoutError", "Framer", "GrblDrives", "GrblError", "Inclinometer",
           "InclinometerError", "Laser2D", "LaserError",
           "LineFramer", "PanTiltHead", "PelcoDFramer", "RequestDamagedError", "RobotBase", "RobotBaseError",
           "ScannerError", "SerialLink", "WallScanner"]

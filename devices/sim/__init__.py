"""Simulated devices: the one simulator server (socket:// on 127.0.0.1), the one seeded fault injector, and the
simulators that need nothing but their protocol (the Pelco-D head; the inclinometer, which reads its tilt from a
callable). Simulators that need the scanning site's physics (GRBL drives, wall scanner) live in
scanner/sim/devices.py, on this server and injector."""

from devices.sim.faults import FAULT_KINDS, FaultConfig, FaultInjector
from devices.sim.inclinometer import InclinometerSim
from devices.sim.pelco_d import HeadFaults, HeadSimulator
from devices.sim.server import DeviceServer, SimDevice

__all__ = ["FAULT_KINDS", "DeviceServer", "FaultConfig", "FaultInjector", "HeadFaults", "HeadSimulator",
           "InclinometerSim", "SimDevice"]

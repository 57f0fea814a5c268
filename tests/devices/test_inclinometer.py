"""The inclinometer's protocol (devices/inclinometer.py): its driver against its simulator over socket://, raw
wire lines against the simulator, and faults on the wire."""

from __future__ import annotations

import socket
from collections.abc import Iterator

import numpy as np
import pytest

from devices.crclines import CrcLineFramer, frame_line, unframe_line
from devices.inclinometer import Inclinometer, InclinometerError, TiltReading
from devices.link import SerialLink
from devices.sim import FaultConfig, InclinometerSim
from devices.sim.inclinometer import SIGMA_DEG

TRUE_TILT = (0.083, -0.041)  # degrees, roll and pitch


@pytest.fixture
def sim() -> Iterator[InclinometerSim]:
    with InclinometerSim(lambda: TRUE_TILT, seed=5) as device:
        yield device


def client(url: str, timeout_s: float = 0.3) -> tuple[Inclinometer, SerialLink]:
    link = SerialLink(url, CrcLineFramer(), "inclinometer", timeout_s=timeout_s)
    link.open()
    return Inclinometer(link), link


def raw_exchange(url: str, line: str) -> str:
    """Send one wire line as given (its checksum as written) and return the answer's wire line."""
    with socket.create_connection(("127.0.0.1", int(url.rsplit(":", 1)[1])), timeout=2.0) as conn:
        conn.sendall(line.encode() + b"\n")
        data = b""
        while not data.endswith(b"\n"):
            chunk = conn.recv(4096)
            assert chunk, "the simulator hung up"
            data += chunk
    return data.decode().strip()


def test_readings_are_the_true_tilt_within_the_stated_sigma(sim: InclinometerSim) -> None:
    device, link = client(sim.url)
    try:
        assert device.identify() == "INCLINOMETER SIM 1.0"
        readings = [device.tilt() for _ in range(200)]
        assert device.true_tilt() == TRUE_TILT
    finally:
        link.close()
    assert all(isinstance(r, TiltReading) and r.sigma_roll_deg == r.sigma_pitch_deg == SIGMA_DEG for r in readings)
    values = np.array([[r.roll_deg, r.pitch_deg] for r in readings])
    errors = values - np.array(TRUE_TILT)
    # a fixed bias (the mean) plus fresh noise per reading, each σ/√2: together the stated σ
    assert np.allclose(errors.mean(axis=0), sim.bias_deg, atol=4 * SIGMA_DEG / np.sqrt(2 * len(readings)))
    assert np.allclose(errors.std(axis=0), SIGMA_DEG / np.sqrt(2), rtol=0.2)
    assert np.sqrt(np.mean(errors ** 2)) < 2 * SIGMA_DEG and np.all(np.abs(errors) < 5 * SIGMA_DEG)


def test_bad_checksum_and_unknown_commands_on_the_wire(sim: InclinometerSim) -> None:
    good = frame_line("#4 TILT?")
    damaged = good[:-1] + ("0" if good[-1] != "0" else "1")
    assert unframe_line(raw_exchange(sim.url, damaged)) == "#4 ERR 2 bad checksum"
    assert unframe_line(raw_exchange(sim.url, frame_line("#5 LEVEL?"))) == "#5 ERR 1 unknown command"
    assert unframe_line(raw_exchange(sim.url, frame_line("#6 TILT? 3"))) == "#6 ERR 4 bad argument"
    answer = unframe_line(raw_exchange(sim.url, good))
    assert answer is not None and answer.startswith("#4 OK ") and len(answer.split()) == 6


def test_an_unknown_command_is_one_clear_error(sim: InclinometerSim) -> None:
    device, link = client(sim.url)
    try:
        with pytest.raises(InclinometerError, match=r"inclinometer \(socket://127\.0\.0\.1:\d+\): 'LEVEL\?' -> ERR 1"):
            device.request("LEVEL?")
    finally:
        link.close()


class _RealInclinometer(InclinometerSim):
    """A real device knows no TRUE?; a broken one reports a tilt beyond any standing robot's."""

    broken = False

    def dispatch(self, tag: str, command: str, args: list[str]) -> list[str]:
        if command == "TRUE?":
            return [f"{tag} ERR 1 unknown command"]
        if command == "TILT?" and self.broken:
            return [f"{tag} OK 45.0 0.1 0.01 0.01"]
        return super().dispatch(tag, command, args)


def test_a_real_device_has_no_truth_and_impossible_readings_are_refused() -> None:
    with _RealInclinometer(lambda: TRUE_TILT) as sim:
        device, link = client(sim.url)
        try:
            assert device.true_tilt() is None
            sim.broken = True
            with pytest.raises(InclinometerError, match="a tilt it cannot have"):
                device.tilt()
        finally:
            link.close()


def test_faults_on_the_wire_are_got_over() -> None:
    with InclinometerSim(lambda: TRUE_TILT, seed=2, faults=FaultConfig(rate=0.3, seed=2)) as sim:
        device, link = client(sim.url, timeout_s=0.1)
        try:
            readings = [device.tilt() for _ in range(30)]
            assert device.faults_recovered > 0
        finally:
            link.close()
    assert all(abs(r.roll_deg - TRUE_TILT[0]) < 5 * SIGMA_DEG for r in readings)

"""The wall scanner's conformance checks: the simulator passes every one; simulators broken in one way each
fail exactly the checks that name that way."""

from __future__ import annotations

import re
import time

import pytest
from typer.testing import CliRunner

from arproj.cli import app
from devices.conformance import CHECKS, run_checks
from devices.sim import DeviceServer
from devices.wallscanner import CrcLineFramer, Damaged
from scanner.plan import DriveConfig
from scanner.sensor_model import SensorConfig
from scanner.sim.devices import WallScannerSim
from scanner.sim.world import SimWorld
from scanner.wall import load_wall, shipped_walls


class RealTimeScannerSim(WallScannerSim):
    """The simulator with its clock running in real time, as a sensor board's does (the scanning site's
    clock only moves with the drives): a sampling run buffers many samples."""

    def __init__(self, world: SimWorld) -> None:
        super().__init__(world)
        self.started = time.monotonic()

    def handle(self, line: str | Damaged) -> list[str]:
        self.world.clock_us = int((time.monotonic() - self.started) * 1e6)
        return super().handle(line)


class AcceptsDamagedLines(RealTimeScannerSim):
    def handle(self, line: str | Damaged) -> list[str]:
        return super().handle(line.text.rsplit("*", 1)[0] if isinstance(line, Damaged) else line)


class AnswersUnknownCommandsOk(RealTimeScannerSim):
    def handle(self, line: str | Damaged) -> list[str]:
        answer = super().handle(line)
        return [a.replace("ERR 1 unknown command", "OK") for a in answer]


class SkipsASample(RealTimeScannerSim):
    def handle(self, line: str | Damaged) -> list[str]:
        return [a for a in super().handle(line) if " S 1 " not in a]


class ShortIds(RealTimeScannerSim):
    """Keeps request ids in four digits (a firmware's too small buffer)."""

    def handle(self, line: str | Damaged) -> list[str]:
        answer = super().handle(line)
        if isinstance(line, str) and line.startswith("#"):
            tag = line.split()[0]
            answer = [a.replace(tag, tag[:5], 1) for a in answer]
        return answer


class _BadIdentityCrc(CrcLineFramer):
    def encode(self, frame: str) -> bytes:
        data = super().encode(frame)
        return data[:-1] + (b"0" if data[-1:] != b"0" else b"1") if b"WALLSCAN" in data else data


class SendsABadChecksum(RealTimeScannerSim):
    framer = _BadIdentityCrc


@pytest.fixture
def world() -> SimWorld:
    return SimWorld(load_wall(shipped_walls()["small_test_wall"]), SensorConfig(), DriveConfig(), 0)


def test_the_simulator_passes_every_check(world: SimWorld) -> None:
    with DeviceServer(RealTimeScannerSim(world)) as server:
        results = run_checks(server.url)
    assert [r.name for r in results] == [name for name, _ in CHECKS]
    assert all(r.ok for r in results), "\n".join(r.line() for r in results)
    read_back = next(r for r in results if r.name == "buffer-read-back")
    assert int(read_back.detail.split()[0]) >= 20  # 0.2 s at 200 Hz: a real stream, not one sample


@pytest.mark.parametrize(("device", "failing"), [
    (AcceptsDamagedLines, {"bad-checksum-refused"}),
    (AnswersUnknownCommandsOk, {"unknown-command"}),
    (SkipsASample, {"buffer-read-back"}),
    (ShortIds, {"request-id-echo"}),
    (SendsABadChecksum, {"identify", "answer-checksums"}),
])
def test_a_broken_simulator_fails_the_checks_that_name_its_fault(world: SimWorld, device: type, failing: set) -> None:
    with DeviceServer(device(world)) as server:
        results = run_checks(server.url, timeout_s=0.3)
    assert {r.name for r in results if not r.ok} == failing, "\n".join(r.line() for r in results)
    assert len(results) == len(CHECKS)


def test_devices_check_command(world: SimWorld) -> None:
    runner = CliRunner()
    ok = runner.invoke(app, ["devices-check", "scanner", "--sim"])
    assert ok.exit_code == 0, ok.output
    lines = ok.output.splitlines()
    assert [ln.split()[0] for ln in lines[:len(CHECKS)]] == ["PASS"] * len(CHECKS)
    assert f"{len(CHECKS)} of {len(CHECKS)} checks passed" in lines[-1]
    with DeviceServer(SkipsASample(world)) as server:
        bad = runner.invoke(app, ["devices-check", "scanner", server.url])
    assert bad.exit_code == 1
    assert re.search(r"FAIL buffer-read-back: GET 0 (\d+) ended with 'END \1' after \d+ sample lines", bad.output)
    assert "failed: buffer-read-back" in bad.output.splitlines()[-1]
    refused = runner.invoke(app, ["devices-check", "scanner", "socket://127.0.0.1:1"])
    assert refused.exit_code == 1 and "cannot open the scanner at socket://127.0.0.1:1" in str(refused.exception)

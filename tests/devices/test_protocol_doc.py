"""docs/scanner-protocol.md against the code: its checksum examples computed by the host's CRC, its worked
sessions replayed byte for byte against the simulator through the host's framer, its figures the code's
defaults. The document cannot drift from what the driver and the simulator do."""

from __future__ import annotations

import inspect
import re
from pathlib import Path

import pytest

from devices import conformance
from devices.link import MAX_LINE_BYTES, SerialLink
from devices.wallscanner import GET_CHUNK, CrcLineFramer, Damaged, WallScanner, checksum, frame_line, unframe_line
from scanner.plan import DriveConfig
from scanner.sensor_model import SensorConfig
from scanner.sim.devices import WallScannerSim
from scanner.sim.world import SimWorld
from scanner.wall import load_wall, shipped_walls

DOC = Path(__file__).resolve().parents[2] / "docs" / "scanner-protocol.md"


@pytest.fixture(scope="module")
def text() -> str:
    return DOC.read_text(encoding="utf-8")


def blocks(text: str, language: str) -> list[list[str]]:
    return [b.strip("\n").splitlines() for b in re.findall(rf"```{language}\n(.*?)```", text, re.S)]


def test_the_checksum_examples_are_the_hosts_crc(text: str) -> None:
    (code,) = blocks(text, "python")
    namespace: dict = {}
    exec("\n".join(code), namespace)  # the document's bit-by-bit CRC-32
    flat = " ".join(text.split())  # the document's lines are wrapped
    examples = re.findall(r"CRC-32[^`]*? of the (\d+) bytes `(.+?)` \(([0-9A-F ]+)\),? is ([0-9A-F]{8})", flat)
    assert len(examples) == 2
    for count, body, hex_bytes, value in examples:
        data = body.encode("ascii")
        assert int(count) == len(data) and bytes.fromhex(hex_bytes) == data
        assert checksum(body) == value == f"{namespace['crc32'](data):08X}"
    sent = re.search(r"the host sends `(.+?)`", flat)
    assert sent is not None and sent.group(1) == frame_line(examples[0][1])


def test_the_worked_sessions_are_what_the_simulator_answers(text: str) -> None:
    sessions = blocks(text, "wire")
    assert len(sessions) == 2
    world = SimWorld(load_wall(shipped_walls()["small_test_wall"]), SensorConfig(), DriveConfig(), 0)
    world.clock_us = 1_000_000
    device = WallScannerSim(world)
    commands = set()
    for lines in sessions:
        expected: list[str] = []
        answers: list[str] = []
        for line in lines:
            if line.startswith("…"):
                ms = re.fullmatch(r"… (\d+) ms", line)
                assert ms is not None, line
                world.clock_us += 1000 * int(ms.group(1))
                continue
            direction, wire = line[:2], line[2:]
            assert direction in ("> ", "< "), line
            if direction == "< ":
                body = unframe_line(wire)
                assert body is not None, f"the document's answer {wire!r} has a wrong checksum"
                expected.append(wire)
                continue
            assert answers == expected, "answers before this request"
            (frame,) = CrcLineFramer().feed(wire.encode("ascii") + b"\n")  # the device's framer, on the wire line
            if not isinstance(frame, Damaged):
                assert CrcLineFramer().encode(frame) == wire.encode("ascii")  # what the host's framer sends
                commands.add(frame.split()[1])
            answers += [CrcLineFramer().encode(a).decode("ascii") for a in device.handle(frame)]
        assert answers == expected
    table = set(re.findall(r"^\| `#<id> ([A-Z?]+)", text, re.M))
    assert table == {"ID?", "CLK?", "ARM", "DISARM", "GET"} and table <= commands | {"FOO"}


def test_the_error_table_is_the_protocols(text: str) -> None:
    rows = dict(re.findall(r"^\| (\d) \| ([a-z /]+?) \|", text, re.M))
    assert rows == {"1": "unknown command", "2": "bad checksum", "3": "not armed / no buffer", "4": "bad argument"}
    assert (conformance.ERR_UNKNOWN, conformance.ERR_CHECKSUM, conformance.ERR_STATE,
            conformance.ERR_ARGUMENT) == (1, 2, 3, 4)


def test_the_documents_figures_are_the_codes_defaults(text: str) -> None:
    link = inspect.signature(SerialLink).parameters
    flat = " ".join(text.split())  # the document's lines are wrapped
    assert f"SerialLink(baudrate={link['baudrate'].default})" in flat
    assert f"SerialLink(timeout_s={link['timeout_s'].default})" in flat
    retries = inspect.signature(WallScanner).parameters["retries"].default
    assert f"up to {retries} more times (`WallScanner(retries={retries})`)" in flat
    assert f"at most {GET_CHUNK} samples (`GET_CHUNK`)" in flat
    assert f"longer than {MAX_LINE_BYTES} bytes" in flat
    assert f"ids 1, 4242, {conformance.MAX_ID}" in flat

"""Bounded device I/O (issue 24 item 5): a request ends within its tries' deadlines whatever the device sends —
status lines streamed forever, CRC-valid answers to other requests, bytes that never end a line, a multi-line
answer that never ends, a device that vanishes mid-line — and a simulator serves one controlling host, turning
away a second one with a line that the host reports.

A misbehaving device streams for STREAM_LIMIT_S, far beyond the host's bound ((retries + 1) × timeout); the host
must give up while it is still streaming (with the deadline restarted on every line it waited until the stream
ended)."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable

import pytest

from devices.errors import DeviceError, DeviceResetError, DeviceTimeoutError
from devices.grbl import GrblDrives
from devices.link import MAX_LINE_BYTES, LineFramer, SerialLink
from devices.sim.server import DeviceServer
from devices.wallscanner import CrcLineFramer, WallScanner, frame_line
from scanner.plan import DriveConfig
from scanner.sensor_model import SensorConfig
from scanner.sim.devices import WallScannerSim
from scanner.sim.world import SimWorld
from scanner.wall import load_wall, shipped_walls

TIMEOUT_S = 0.1
RETRIES = 2
STREAM_LIMIT_S = 30.0  # 100 × the host's bound of 3 × 0.1 s


class RogueDevice(threading.Thread):
    """A device on socket://127.0.0.1 whose k-th connection is handled by talk(conn, k, rogue)."""

    def __init__(self, talk: Callable[[socket.socket, int, RogueDevice], None]) -> None:
        super().__init__(daemon=True)
        self.talk = talk
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.listener.settimeout(0.05)
        self.url = f"socket://127.0.0.1:{self.listener.getsockname()[1]}"
        self.stopping = threading.Event()
        self.host_left_while_streaming = threading.Event()
        self.start()

    def run(self) -> None:
        k = 0
        while not self.stopping.is_set():
            try:
                conn, _ = self.listener.accept()
            except TimeoutError:
                continue
            with conn:
                self.talk(conn, k, self)
            k += 1

    def stream(self, conn: socket.socket, chunk: Callable[[bytes], bytes]) -> None:
        """Send chunk(last request line) every millisecond for STREAM_LIMIT_S, or until the host hangs up."""
        conn.settimeout(0.001)
        end, request, pending = time.monotonic() + STREAM_LIMIT_S, b"", b""
        while time.monotonic() < end and not self.stopping.is_set():
            try:
                data = conn.recv(4096)
                if not data:
                    self.host_left_while_streaming.set()
                    return
                pending += data
                if b"\n" in pending:
                    *lines, pending = pending.split(b"\n")
                    request = lines[-1]
            except TimeoutError:
                pass
            try:
                conn.sendall(chunk(request))
            except OSError:
                self.host_left_while_streaming.set()
                return

    def close(self) -> None:
        self.stopping.set()
        self.join(timeout=5)
        self.listener.close()


def _line(body: str) -> bytes:
    return (frame_line(body) + "\n").encode()


def _tag(request: bytes) -> str:
    return request.decode(errors="replace").split(" ")[0] or "#0"


def _scanner(url: str) -> tuple[SerialLink, WallScanner]:
    link = SerialLink(url, CrcLineFramer(), "wall scanner", timeout_s=TIMEOUT_S, reconnect_attempts=3,
                      reconnect_delay_s=0.01)
    link.open()
    return link, WallScanner(link, retries=RETRIES)


@pytest.mark.parametrize("chatter", ["status lines", "answers to other requests", "no newline ever",
                                     "a multi-line answer without END"])
def test_a_device_that_keeps_talking_cannot_hold_a_request(chatter: str) -> None:
    talks = {
        "answers to other requests": lambda request: _line("#999 OK WALLSCAN OTHER 1.0"),
        "no newline ever": lambda request: b"A" * 1024,
        "a multi-line answer without END": lambda request: _line(f"{_tag(request)} S 0 0 1 2 3"),
    }
    if chatter == "status lines":  # GRBL homing: `<Home|…>` reports, never the `ok`
        rogue = RogueDevice(lambda conn, k, r: r.stream(conn, lambda request: b"<Home|MPos:0.000,0.000,0.000>\n"))
        link = SerialLink(rogue.url, LineFramer(), "drives", timeout_s=TIMEOUT_S)
        link.open()
        request: Callable[[], object] = GrblDrives(link, retries=RETRIES, homing_timeout_s=TIMEOUT_S).home
    else:
        rogue = RogueDevice(lambda conn, k, r: r.stream(conn, talks[chatter]))
        link, scanner = _scanner(rogue.url)
        request = scanner.identify if chatter != "a multi-line answer without END" else lambda: scanner.fetch(5)
    try:
        with pytest.raises(DeviceTimeoutError, match=f"after {RETRIES + 1} tries of") as refused:
            request()
        link.close()
        assert rogue.host_left_while_streaming.wait(5.0)  # the host gave up while the device still talked
        if chatter == "no newline ever":
            assert link.framer.rejected_bytes > MAX_LINE_BYTES  # the endless "line" was dropped, not kept
        if chatter == "a multi-line answer without END":  # cut at the lines asked for, not at the deadline
            assert "more than 5 lines before END" in str(refused.value)
    finally:
        link.close()
        rogue.close()


def test_a_device_that_vanishes_mid_line_is_reconnected_and_the_half_line_dropped() -> None:
    def talk(conn: socket.socket, k: int, rogue: RogueDevice) -> None:
        request = conn.recv(4096).split(b"\n")[0]
        if k == 0:
            conn.sendall(_line(f"{_tag(request)} OK WALLSCAN GMS120 1.0")[:12])  # half a line, then gone
            return
        conn.sendall(_line(f"{_tag(request)} OK WALLSCAN GMS120 1.0"))
        time.sleep(0.5)

    rogue = RogueDevice(talk)
    link, scanner = _scanner(rogue.url)
    try:
        with pytest.raises(DeviceResetError, match="scanner reconnected"):  # the protocol redoes its step
            scanner.identify()
        assert scanner.identify() == "WALLSCAN GMS120 1.0" and link.reconnects == 1
    finally:
        link.close()
        rogue.close()


def test_a_simulator_serves_one_host_and_refuses_a_second_saying_so() -> None:
    wall = load_wall(shipped_walls()["small_test_wall"])
    world = SimWorld(wall, SensorConfig(), DriveConfig(), 0)
    with DeviceServer(WallScannerSim(world)) as server:
        first_link, first = _scanner(server.url)
        second_link, second = _scanner(server.url)
        try:
            assert first.identify().startswith("WALLSCAN")
            with pytest.raises(DeviceError, match=r"refused this connection: simulated wallscanner .* already "
                                                  r"has a controlling host"):
                second.identify()
            assert server.refused >= 1
            assert first.identify().startswith("WALLSCAN")  # the controlling host never noticed
            first_link.close()
            second_link.open()  # the simulator is free again: the next host takes control
            assert second.identify().startswith("WALLSCAN")
        finally:
            first_link.close()
            second_link.close()


def test_a_simulator_drops_an_endless_line_and_answers_the_next_request() -> None:
    wall = load_wall(shipped_walls()["small_test_wall"])
    server = DeviceServer(WallScannerSim(SimWorld(wall, SensorConfig(), DriveConfig(), 0)))
    with server, socket.create_connection(("127.0.0.1", server.port)) as conn:
        for _ in range(64):  # 4 MiB without a newline
            conn.sendall(b"x" * 65536)
        conn.sendall(b"\n" + _line("#7 ID?"))
        conn.settimeout(10.0)
        answer = b""
        while _line("#7 OK WALLSCAN GMS120-SIM 1.0") not in answer:
            answer += conn.recv(4096)

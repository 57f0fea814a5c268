"""The one simulator server: a simulated device served as a `socket://127.0.0.1:PORT` serial URL.

A TCP server thread on loopback that frames what arrives with the device's framer, hands each frame to the
device and sends its answers, every frame through the fault injector (devices/sim/faults.py). It serves one
controlling host at a time: another program that connects meanwhile gets one `BUSY …` line saying so and is
hung up on (devices.link turns that into a DeviceError naming it), so nothing else can move a simulated device
under the session that drives it. Its framer bounds what it buffers (a "line" without a newline is dropped
past MAX_LINE_BYTES). The host code opens the URL as it would a real port, so simulation and hardware share
one code path. A device is a `SimDevice`: its framer, a greeting on connect, a reset on (re)connect, and one
list of answers per frame.
"""

from __future__ import annotations

import contextlib
import select
import socket
import threading
import time
from abc import ABC, abstractmethod
from collections.abc import Callable
from typing import Any, Self

from devices.link import BUSY_PREFIX, Framer
from devices.sim.faults import FaultConfig, FaultInjector

REFUSE_WAIT_S = 0.5  # the longest a refused host's open() may take before it asks something
REFUSE_LINGER_S = 5.0  # the longest a refused host may take to read the BUSY line and hang up


class SimDevice(ABC):
    """What a DeviceServer serves. Subclasses set `name` and `framer` and implement handle()."""

    name = "device"
    framer: Callable[[], Framer[Any, Any]]  # a fresh framer per connection

    def greeting(self) -> list[Any]:
        """Frames sent when a host connects (GRBL's banner), without faults."""
        return []

    def reset(self) -> None:
        """The device restarts: a host (re)connected. Devices that keep their state across a reconnect do
        nothing."""
        return

    def chatter(self, answer: Any) -> Any | None:
        """A frame this device might send instead of `answer` while it keeps talking (a status report, an
        answer under another id or address); None: junk frames of the framer's noise."""
        return None

    def answers(self, frame: Any) -> bool:
        """Whether the device answers this frame; one it obeys silently (a set command) may be ignored by the
        fault injector, since only the device's behaviour shows that it was lost."""
        return True

    @abstractmethod
    def handle(self, frame: Any) -> list[Any]:
        """The answer frames to one received frame (none: nothing is sent)."""


class DeviceServer(threading.Thread):
    """A TCP server on 127.0.0.1 for one simulated device and one controlling host at a time."""

    def __init__(self, device: SimDevice, faults: FaultConfig | None = None, stream: int = 0) -> None:
        super().__init__(daemon=True, name=f"sim-{device.name}")
        self.device = device
        self.faults = FaultInjector(faults or FaultConfig(), stream)
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.listener.settimeout(0.05)
        self.port = self.listener.getsockname()[1]
        self.stopping = threading.Event()
        self.down_until = 0.0
        self.connections = 0
        self.refused = 0  # connections turned away while a host was connected
        self._conn: socket.socket | None = None

    @property
    def url(self) -> str:
        return f"socket://127.0.0.1:{self.port}"

    def stop(self) -> None:
        self.stopping.set()
        self.join(timeout=2.0)
        self.listener.close()

    def drop_connection(self) -> None:
        """The device vanishes for a moment (power blip, cable): the open connection is closed; the port stays
        reachable, so a host that reconnects gets it back."""
        conn = self._conn
        if conn is not None:
            with contextlib.suppress(OSError):
                conn.shutdown(socket.SHUT_RDWR)

    def __enter__(self) -> DeviceServer:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def run(self) -> None:
        while not self.stopping.is_set():
            try:
                conn, _ = self.listener.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            if time.monotonic() < self.down_until:
                conn.close()  # the device is gone for now
                continue
            self.connections += 1
            self.device.reset()
            with conn:
                self._conn = conn
                try:
                    self._serve(conn)
                finally:
                    self._conn = None

    def _refuse_others(self, conn: socket.socket) -> bool:
        """Turn away whoever connects while the host on conn is connected, saying why. False if that host has
        hung up meanwhile (then a new connection is its reconnect, for run() to accept)."""
        while select.select([self.listener], [], [], 0)[0]:
            timeout = conn.gettimeout()
            conn.setblocking(False)  # a peek that must not wait (with a timeout set, recv would wait first)
            try:
                if conn.recv(1, socket.MSG_PEEK) == b"":
                    return False
            except BlockingIOError:
                pass  # connected, nothing to read
            except OSError:
                return False
            finally:
                conn.settimeout(timeout)
            try:
                other, address = self.listener.accept()
            except OSError:
                return True  # the one who knocked is gone already
            self.refused += 1
            threading.Thread(target=self._turn_away, args=(other, address), daemon=True,
                             name=f"sim-{self.device.name}-refusal").start()
        return True

    def _turn_away(self, other: socket.socket, address: tuple[str, int]) -> None:
        """Say BUSY to a host that connected while another drives the device, then hang up, so that the line
        reaches it. pyserial's socket:// open() discards whatever arrives before it returns, so the line waits
        for the host's first request (or REFUSE_WAIT_S); and the hang-up waits for the host to read the line
        and close (or REFUSE_LINGER_S), since closing with its request unread sends a reset, which can discard
        the line before the host reads it. A thread of its own: the controlling host is never kept waiting."""
        line = (BUSY_PREFIX + f"simulated {self.device.name} on port {self.port} already has a controlling host; "
                f"one program drives it at a time (refused {address[0]}:{address[1]})\n".encode())
        with other, contextlib.suppress(OSError):
            select.select([other], [], [], REFUSE_WAIT_S)
            other.sendall(line)
            other.shutdown(socket.SHUT_WR)
            end = time.monotonic() + REFUSE_LINGER_S
            while not self.stopping.is_set() and time.monotonic() < end:
                if select.select([other], [], [], 0.05)[0] and not other.recv(65536):
                    return  # the host read the line and hung up

    def _keep_talking(self, conn: socket.socket, framer: Framer[Any, Any], answer: Any, kind: str) -> bool:
        """Send chatter frames (stream) or bytes that never end a frame (flood) instead of `answer` until the
        host sends again or hangs up, at most talk_s; at most talk_bytes_s bytes a second, as a device behind a
        UART's few bytes of buffer can (a socket would queue megabytes the host must read before the answer).
        False when the host is gone."""
        if kind == "flood":
            chunk = framer.noise.endless * 16384
        else:
            said = self.device.chatter(answer)
            chunk = (self.faults.junk_frame(framer.noise) if said is None else framer.encode(said)) + framer.terminator
        pause_s = max(0.001, len(chunk) / self.faults.config.talk_bytes_s)
        end = time.monotonic() + self.faults.config.talk_s
        while not self.stopping.is_set() and time.monotonic() < end:
            if select.select([conn], [], [], pause_s)[0]:
                return True  # the host said something (or hung up): the serve loop reads it
            try:
                conn.sendall(chunk)
            except TimeoutError:
                continue  # the host is not reading: its buffer is full, wait for it
            except OSError:
                return False
        return True

    def _serve(self, conn: socket.socket) -> None:
        conn.settimeout(0.05)
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        framer = self.device.framer()
        greeting = self.device.greeting()
        if greeting:
            conn.sendall(b"".join(framer.encode(frame) + framer.terminator for frame in greeting))
        while not self.stopping.is_set():
            if not self._refuse_others(conn):
                return
            try:
                chunk = conn.recv(65536)
            except TimeoutError:
                continue
            except OSError:
                return
            if not chunk:
                return
            for frame in framer.feed(chunk):
                if not self.device.answers(frame) and self.faults.ignores():
                    continue
                out = bytearray()
                for index, answer in enumerate(self.device.handle(frame)):
                    fault = self.faults.pick(allow_disconnect=index == 0)
                    if fault in ("disconnect", "vanish"):  # gone before the frame, or in the middle of it
                        self.down_until = time.monotonic() + self.faults.config.down_s
                        if fault == "vanish":
                            data = framer.encode(answer)
                            out += data[:len(data) // 2]
                        with contextlib.suppress(OSError):
                            conn.sendall(bytes(out))
                            conn.shutdown(socket.SHUT_RDWR)
                        return
                    if fault in ("stream", "flood"):  # this answer is never sent: the host must ask again
                        with contextlib.suppress(OSError):
                            conn.sendall(bytes(out))
                        out = bytearray()
                        if not self._keep_talking(conn, framer, answer, fault):
                            return
                        break
                    out += self.faults.apply(fault, framer.encode(answer), framer.noise, framer.terminator)
                if out and self.faults.config.delay_s > 0:
                    time.sleep(self.faults.config.delay_s)
                try:
                    conn.sendall(bytes(out))
                except OSError:
                    return


class ServedDevice:
    """A simulator that owns its DeviceServer (started in its __init__): the URL it is reached at, closing it,
    and `with`."""

    server: DeviceServer

    @property
    def url(self) -> str:
        return self.server.url

    def close(self) -> None:
        self.server.stop()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

"""A simulated Pelco-D pan/tilt head listening on socket://127.0.0.1:PORT, with seeded fault injection.

It is reached exactly like the real head (PanTiltHead(sim.url)), so tests and `--sim` exercise the real
driver. The simulated head moves at a finite speed, and its physical angles can differ from what its encoder
reports (`slip_deg`: the mount slipped; the encoder does not know) — the case the session must catch with
its cameras. Faults: dropped replies, corrupted checksums, garbage bytes, slow replies, ignored set
commands, and a dead head that answers nothing.
"""

from __future__ import annotations

import contextlib
import socket
import socketserver
import threading
import time
from dataclasses import dataclass

import numpy as np

from arproj.devices import pelco_d


@dataclass
class HeadFaults:
    """Fault injection; rates are probabilities per message. Seeded, so a run is reproducible."""

    drop_reply_rate: float = 0.0
    corrupt_reply_rate: float = 0.0
    garbage_rate: float = 0.0
    ignore_command_rate: float = 0.0
    reply_delay_s: float = 0.0
    dead: bool = False
    slip_deg: tuple[float, float] = (0.0, 0.0)  # physical minus reported (pan, tilt)


class HeadSimulator:
    """Pelco-D head on a local TCP port. Use as a context manager; `url` is what the driver opens."""

    def __init__(self, address: int = 1, speed_deg_s: float = 120.0, faults: HeadFaults | None = None,
                 seed: int = 0, initial_deg: tuple[float, float] = (0.0, 0.0)) -> None:
        self.address = address
        self.speed_deg_s = speed_deg_s
        self.faults = faults or HeadFaults()
        self._rng = np.random.default_rng(seed)
        self._lock = threading.Lock()
        self._start = np.array(initial_deg, dtype=np.float64)
        self._target = self._start.copy()
        self._t_start = time.monotonic()
        self.messages_received = 0
        self.faults_injected = 0
        self._connections: list[socket.socket] = []
        simulator = self

        class Handler(socketserver.BaseRequestHandler):
            def handle(self) -> None:
                simulator._serve(self.request)

        class Server(socketserver.ThreadingTCPServer):
            daemon_threads = True
            allow_reuse_address = True

        self._server = Server(("127.0.0.1", 0), Handler)
        self._thread = threading.Thread(target=self._server.serve_forever, name="head-sim", daemon=True)
        self._thread.start()

    @property
    def url(self) -> str:
        host, port = self._server.server_address[:2]
        return f"socket://{host}:{port}"

    def close(self) -> None:
        self._server.shutdown()
        self._server.server_close()

    def __enter__(self) -> HeadSimulator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- the simulated mechanics -----------------------------------------------------------------------
    def reported_deg(self) -> tuple[float, float]:
        """(pan, tilt) the encoder reports now (moving towards the target at speed_deg_s)."""
        with self._lock:
            pan, tilt = self._current_locked()
            return float(pan), float(tilt)

    def true_deg(self) -> tuple[float, float]:
        """(pan, tilt) the head physically has: the reported angles plus the slip."""
        pan, tilt = self.reported_deg()
        return float(pan + self.faults.slip_deg[0]), float(tilt + self.faults.slip_deg[1])

    def _current_locked(self) -> np.ndarray:
        delta = self._target - self._start
        distance = float(np.max(np.abs(delta)))
        if distance == 0.0:
            return self._target.copy()
        fraction = min(1.0, (time.monotonic() - self._t_start) * self.speed_deg_s / distance)
        return self._start + fraction * delta

    def _set_axis(self, axis: int, angle: float) -> None:
        with self._lock:
            target = self._target.copy()  # the other axis keeps moving to its own target
            target[axis] = angle
            self._start = self._current_locked()
            self._target = target
            self._t_start = time.monotonic()

    # -- the wire --------------------------------------------------------------------------------------
    def drop_connections(self) -> None:
        """The head vanishes for a moment (power blip, cable): every open connection is closed; the port stays
        reachable, so a driver that reconnects gets it back."""
        for conn in list(self._connections):
            with contextlib.suppress(OSError):
                conn.shutdown(socket.SHUT_RDWR)
                conn.close()
        self._connections.clear()

    def _serve(self, conn: socket.socket) -> None:
        self._connections.append(conn)
        decoder = pelco_d.FrameDecoder()
        conn.settimeout(0.5)
        while True:
            try:
                data = conn.recv(256)
            except TimeoutError:
                continue
            except OSError:
                return
            if not data:
                return
            for frame in decoder.feed(data):
                reply = self._handle(frame)
                if reply:
                    try:
                        conn.sendall(reply)
                    except OSError:
                        return

    def _chance(self, rate: float) -> bool:
        hit = rate > 0 and self._rng.random() < rate
        self.faults_injected += int(hit)
        return hit

    def _handle(self, frame: pelco_d.Frame) -> bytes:
        self.messages_received += 1
        f = self.faults
        if frame.address != self.address or f.dead:
            return b""
        if frame.command2 in (pelco_d.SET_PAN, pelco_d.SET_TILT):
            if not self._chance(f.ignore_command_rate):
                axis = 0 if frame.command2 == pelco_d.SET_PAN else 1
                self._set_axis(axis, pelco_d.data_to_angle(frame.data))
            return b""
        if frame.command2 not in pelco_d.REPLY_FOR_QUERY:
            return b""  # commands this head does not know are ignored, as real heads do
        if self._chance(f.drop_reply_rate):
            return b""
        pan, tilt = self.reported_deg()
        angle = pan if frame.command2 == pelco_d.QUERY_PAN else tilt
        reply = bytearray(pelco_d.encode(self.address, pelco_d.REPLY_FOR_QUERY[frame.command2],
                                         pelco_d.angle_to_data(angle)))
        if self._chance(f.corrupt_reply_rate):
            reply[6] ^= 0x5A
        if self._chance(f.garbage_rate):
            reply = bytearray(self._rng.integers(0, 256, size=int(self._rng.integers(1, 9)), dtype=np.uint8)
                              .tobytes()) + reply
        if f.reply_delay_s > 0:
            time.sleep(f.reply_delay_s)
        return bytes(reply)

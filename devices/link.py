"""One connection to a device over a pyserial URL (a real port, `socket://host:port`, `loop://`), framed by the
protocol's framer.

As pyserial's `threaded` module splits a connection from its Packetizer/LineReader, the link here knows bytes,
deadlines and recovery, and a framer knows how frames sit in the byte stream: `LineFramer` (text lines, GRBL),
the wall scanner's CRC lines (devices/wallscanner.py) and Pelco-D's 7-byte frames (devices/pelco_d.py). On top,
`exchange()` is the one retry loop of every request/answer protocol, with a lock held for the whole exchange
and one deadline per try that nothing the device sends can extend (status lines, stale answers, noise); it
reconnects a device that went away. Memory is bounded too: a "line" longer than MAX_LINE_BYTES is dropped, and
a device that refuses a second host (BUSY_PREFIX, as the simulators do) is one clear DeviceError, not a
reconnect loop. The protocols say only what their frames mean.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Generic, Protocol, TypeVar

import serial

from devices.errors import DeviceError, DeviceTimeoutError, DisconnectedError, FrameTimeoutError, RequestDamagedError

POLL_S = 0.01  # granularity of the read deadline
MAX_LINE_BYTES = 4096  # longer "lines" are garbage: dropped so a device spewing noise cannot exhaust memory
BUSY_PREFIX = b"BUSY "  # a device (simulator) that already has a controlling host sends this line, then hangs up
SOCKET_CLOSE_S = 0.3  # pyserial's socket:// close() sleeps this long ("give the server some time")
_TAIL_BYTES = 256  # the last bytes received, kept to read a BUSY line when the device hangs up

# Framer[Received, Sent]: feed() gives Received frames, encode() takes Sent ones. Most protocols use one type both
# ways; the wall scanner's framer gives strings or Damaged and sends strings.
Received = TypeVar("Received")
Sent = TypeVar("Sent")
Sent_contra = TypeVar("Sent_contra", contravariant=True)
Answer = TypeVar("Answer")


@dataclass(frozen=True)
class Noise:
    """The bytes a wire carries, for the fault injector to imitate: inserted garbage bytes from range
    [insert[0], insert[1]), junk frames of junk_length[0]..junk_length[1]-1 bytes from [junk[0], junk[1]);
    endless: a byte that never completes a frame, what a device sends that talks without ever ending one."""

    insert: tuple[int, int]
    junk: tuple[int, int]
    junk_length: tuple[int, int]
    endless: bytes = b"~"


# Printable ASCII: inserted bytes without space (a space would split fields); junk lines may hold spaces.
TEXT_NOISE = Noise(insert=(33, 127), junk=(32, 127), junk_length=(1, 30))


class Framer(Protocol[Received, Sent_contra]):
    """Frames in and out of a byte stream (pyserial's Packetizer, without the thread).

    feed() takes received bytes and returns the complete frames they finish (keeping a partial one for the
    next call); it never raises: bytes that cannot be a frame are counted in rejected_bytes and dropped.
    encode() gives a frame's bytes without the terminator, which is sent after it.
    """

    terminator: bytes
    noise: Noise

    @property
    def rejected_bytes(self) -> int: ...  # read-only: a framer wrapping another one passes its count on

    def feed(self, data: bytes) -> list[Received]: ...

    def encode(self, frame: Sent_contra) -> bytes: ...

    def clear(self) -> None: ...


class LineFramer:
    """Text lines ending in `\\n` (a `\\r` before it is dropped), decoded as ASCII leniently; a "line" longer
    than max_bytes is garbage and dropped, so a device spewing noise cannot exhaust memory."""

    terminator = b"\n"
    noise = TEXT_NOISE

    def __init__(self, max_bytes: int = MAX_LINE_BYTES) -> None:
        self.max_bytes = max_bytes
        self._buffer = bytearray()
        self.rejected_bytes = 0

    def feed(self, data: bytes) -> list[str]:
        self._buffer.extend(data)
        lines = []
        while (newline := self._buffer.find(b"\n")) >= 0:
            lines.append(bytes(self._buffer[:newline]).decode("ascii", errors="replace").strip("\r"))
            del self._buffer[:newline + 1]
        if len(self._buffer) > self.max_bytes:
            self.rejected_bytes += len(self._buffer)
            self._buffer.clear()
        return lines

    def encode(self, frame: str) -> bytes:
        return frame.encode("ascii", errors="replace")

    def clear(self) -> None:
        self._buffer.clear()


class SerialLink(Generic[Received, Sent]):
    """A framed connection to one device.

    url : pyserial URL; framer : the protocol's framer; timeout_s : default deadline for one answer frame;
    reconnect_attempts and reconnect_delay_s bound how long a vanished device is waited for (never a hang);
    hint : what a person should do when the device fails for good (ends every DeviceError of the link).
    """

    def __init__(self, url: str, framer: Framer[Received, Sent], name: str = "device", timeout_s: float = 0.5,
                 baudrate: int = 115200, reconnect_attempts: int = 50, reconnect_delay_s: float = 0.02,
                 hint: str = "check the cable, power and baud rate of the device") -> None:
        self.url = url
        self.framer = framer
        self.name = name
        self.timeout_s = timeout_s
        self.baudrate = baudrate
        self.reconnect_attempts = reconnect_attempts
        self.reconnect_delay_s = reconnect_delay_s
        self.hint = hint
        self.lock = threading.RLock()
        self.reconnects = 0  # protocols compare this to notice that the device was reset
        self._port: serial.SerialBase | None = None
        self._frames: deque[Received] = deque()
        self._tail = b""
        self.faults_recovered = 0  # timeouts, resends and reconnects that exchange() got over

    # ------------------------------------------------------------------ connection
    def open(self) -> None:
        try:
            self._port = serial.serial_for_url(self.url, baudrate=self.baudrate, timeout=POLL_S,
                                               write_timeout=self.timeout_s)
        except (serial.SerialException, ValueError, OSError) as err:
            raise DisconnectedError(f"cannot open the {self.name} at {self.url}: {err}", self.hint) from None
        self.framer.clear()
        self._frames.clear()
        self._tail = b""

    def close(self) -> None:
        if self._port is not None:
            with contextlib.suppress(serial.SerialException, OSError):
                self._port.close()
            self._port = None

    def reconnect(self) -> None:
        """Close and reopen with bounded retries; raises DeviceError when the device does not come back."""
        self.close()
        last = ""
        for attempt in range(self.reconnect_attempts):
            time.sleep(self.reconnect_delay_s * min(1 + attempt, 10))
            try:
                self.open()
                self.reconnects += 1
                return
            except DisconnectedError as err:
                last = str(err)
        raise DeviceError(f"{self.name} at {self.url} did not come back after {self.reconnect_attempts} attempts "
                          f"({last})", self.hint)

    def __enter__(self) -> SerialLink[Received, Sent]:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ request / answer
    def exchange(self, request: Callable[[], Sent], answer: Callable[[Received], Answer | None], *, retries: int,
                 on_reconnect: Callable[[], Exception] | None = None, timeout_s: float | None = None,
                 what: str | None = None) -> Answer:
        """Send request() and give each frame that comes back to answer() until it returns a value.

        answer returns None to keep listening (noise, a stale frame), raises RequestDamagedError when the
        device reports the request damaged, and raises the protocol's own errors for what a person must see.
        timeout_s (default: the link's) bounds each try whatever the device sends meanwhile: a device streaming
        status lines or answers to other requests cannot keep it waiting. A timeout or a RequestDamagedError
        sends a fresh request() again, at most `retries` times more, then DeviceTimeoutError: a request takes at
        most (retries + 1) * timeout_s, plus reconnects. A disconnect reconnects; then, for a device that lost
        state the protocol relied on, the error on_reconnect() returns is raised once the protocol has dropped
        that state, else (on_reconnect None: nothing was lost) the request is tried again. Holds the lock for
        the whole exchange, so no other request's frames are taken for ours. what names the request in errors
        (default: the frame's repr).
        """
        last_fault, frame = "", None
        try_s = self.timeout_s if timeout_s is None else timeout_s
        with self.lock:
            for _ in range(retries + 1):
                try:
                    self.drain()
                    frame = request()
                    self.send(frame)
                    deadline = time.monotonic() + try_s
                    while True:
                        value = answer(self.receive(deadline=deadline))
                        if value is not None:
                            return value
                except (FrameTimeoutError, RequestDamagedError) as fault:
                    self.faults_recovered += 1
                    last_fault = str(fault)
                except DisconnectedError as fault:
                    self.faults_recovered += 1
                    last_fault = str(fault)
                    self.reconnect()
                    if on_reconnect is not None:
                        raise on_reconnect() from None
        raise DeviceTimeoutError(f"{self.name} at {self.url} did not answer {what or repr(frame)} after {retries + 1} "
                                 f"tries of {try_s:.2g} s (last: {last_fault})", self.hint)

    def exchange_bound_s(self, retries: int, timeout_s: float | None = None) -> float:
        """The longest exchange(retries=retries, timeout_s=timeout_s) takes whatever the device sends, as its
        docstring says: every try runs to its deadline, plus the poll that crosses it, and ends in the slowest
        reconnect (every attempt's wait, and the close before it: pyserial's socket:// close sleeps 0.3 s to give
        a server time). Scheduling delays of a loaded host come on top."""
        try_s = self.timeout_s if timeout_s is None else timeout_s
        close_s = SOCKET_CLOSE_S if self.url.startswith("socket://") else 0.0
        reconnect_s = close_s + sum(self.reconnect_delay_s * min(1 + a, 10) for a in range(self.reconnect_attempts))
        return (retries + 1) * (try_s + POLL_S + reconnect_s)

    # ------------------------------------------------------------------ frames
    def send(self, frame: Sent) -> None:
        if self._port is None:
            raise DisconnectedError(f"{self.name} at {self.url}: not open")
        try:
            self._port.write(self.framer.encode(frame) + self.framer.terminator)
        except (serial.SerialException, OSError) as err:
            raise DisconnectedError(f"{self.name} at {self.url}: write failed ({err})") from None

    def receive(self, timeout_s: float | None = None, *, deadline: float | None = None) -> Received:
        """The next complete frame. Waits until `deadline` (time.monotonic()), else timeout_s (default: the
        link's), from now. Raises FrameTimeoutError / DisconnectedError."""
        start = time.monotonic()
        if deadline is None:
            deadline = start + (self.timeout_s if timeout_s is None else timeout_s)
        while True:
            if self._frames:
                return self._frames.popleft()
            if time.monotonic() >= deadline:
                raise FrameTimeoutError(f"{self.name} at {self.url}: no answer within {deadline - start:.3g} s")
            self._frames.extend(self.framer.feed(self._read()))

    def drain(self) -> list[Received]:
        """Discard (and return) whatever complete frames are already waiting: stale answers after a retry."""
        if self._port is None:
            return []
        try:
            self._port.timeout = 0
            self._frames.extend(self.framer.feed(self._kept(self._port.read(65536))))
            self._port.timeout = POLL_S
        except (serial.SerialException, OSError) as err:
            raise self._gone(err) from None
        stale = list(self._frames)
        self._frames.clear()
        return stale

    def _read(self) -> bytes:
        """What arrives within one poll interval (possibly nothing)."""
        if self._port is None:
            raise DisconnectedError(f"{self.name} at {self.url}: not open")
        try:
            chunk = self._port.read(1)  # waits up to the port's 10 ms timeout
            if chunk:  # then take everything already there without waiting (socket:// in_waiting is 0/1)
                self._port.timeout = 0
                chunk += self._port.read(65536)
                self._port.timeout = POLL_S
        except (serial.SerialException, OSError) as err:
            raise self._gone(err) from None
        return self._kept(chunk)

    def _kept(self, chunk: bytes) -> bytes:
        if chunk:
            self._tail = (self._tail + chunk)[-_TAIL_BYTES:]
        return chunk

    def _gone(self, err: Exception) -> DeviceError:
        """The error for a read that failed: the device's own refusal if it sent one (a BUSY line), else a
        DisconnectedError that exchange() recovers from."""
        busy = self._tail.rfind(BUSY_PREFIX)
        if busy >= 0:
            said = self._tail[busy + len(BUSY_PREFIX):].split(b"\n")[0].decode("ascii", errors="replace").strip()
            return DeviceError(f"{self.name} at {self.url} refused this connection: {said}",
                               "stop the other program that drives it, or give this one its own simulator")
        return DisconnectedError(f"{self.name} at {self.url}: read failed ({err})")

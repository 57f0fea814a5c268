"""Recorded serial sessions: what a host sent and a device answered, byte for byte, to replay in a test.

A recording is pyserial's spy:// hexdump (serial.urlhandler.protocol_spy.FormatHexdump): one line per 16 bytes,
`TTTTTT.TTT TX   0000  48 45 ...  HE..` for bytes the host wrote, `RX` for bytes it read, other labels for
events. Two URL handlers (devices/urlhandler/, found by pyserial once `devices` is imported) make and play them:

    record://URL?file=F   opens URL (any pyserial URL, socket:// too, which spy:// cannot wrap) and writes F in
                          spy's format, marking each connection (`OPEN`) and a device that went away (`EOF`);
                          F is started afresh by the first connection of a process, appended to by reconnects
    replay://F            plays F back: what the host writes must equal the recorded TX bytes (else a
                          DeviceError naming the first differing byte); the RX bytes recorded after them are
                          read back; a recorded `EOF` closes the connection there and the next open continues with
                          the next recorded connection. `finish_replay(F)` says what was left unplayed.

A capture made with spy:// on a real port (`spy:///dev/ttyUSB0?file=F`) replays the same way (it holds one
connection, without OPEN lines). Replays are deterministic for request/answer protocols whose recorded answers
came within the host's deadline; an answer that came late in the recording may be taken in time on replay.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from pathlib import Path

from devices.errors import DeviceError

HEX_COLUMNS = slice(22, 71)  # where FormatHexdump puts a row's hex bytes: after "TTTTTT.TTT LLLL OOOO  "


@dataclass
class Connection:
    """One recorded connection: events ("TX" | "RX" | "EOF", bytes) in order, consecutive ones merged."""

    events: list[tuple[str, bytes]] = field(default_factory=list)
    index: int = 0  # the event being played
    offset: int = 0  # bytes of it played

    def add(self, kind: str, data: bytes = b"") -> None:
        if self.events and self.events[-1][0] == kind and kind != "EOF":
            self.events[-1] = (kind, self.events[-1][1] + data)
        else:
            self.events.append((kind, data))

    def _advance(self, count: int) -> None:
        self.offset += count
        if self.offset >= len(self.events[self.index][1]):
            self.index, self.offset = self.index + 1, 0

    def write(self, data: bytes, path: str) -> None:
        """The host writes `data`: it must be the recorded TX bytes, all recorded RX before them read."""
        sent = 0
        while sent < len(data):
            if self.index >= len(self.events) or self.events[self.index][0] != "TX":
                kind = "the end" if self.index >= len(self.events) else self.events[self.index][0]
                raise DeviceError(f"replay of {path}: the host wrote {data[sent:sent + 40]!r} where the recording "
                                  f"has {kind} (event {self.index})", "the host's code or settings differ from "
                                  "the recorded session's")
            expected = self.events[self.index][1][self.offset:self.offset + len(data) - sent]
            got = data[sent:sent + len(expected)]
            if got != expected:
                at = next(i for i, (a, b) in enumerate(zip(got, expected, strict=False)) if a != b)
                raise DeviceError(f"replay of {path}: the host wrote {got[max(0, at - 20):at + 20]!r} where the "
                                  f"recording has {expected[max(0, at - 20):at + 20]!r} (event {self.index})",
                                  "the host's code or settings differ from the recorded session's")
            self._advance(len(expected))
            sent += len(expected)

    def read(self, size: int) -> bytes | None:
        """Up to `size` recorded RX bytes that follow what the host wrote; b"" when the device said nothing
        more there; None at a recorded EOF (the device went away)."""
        if self.index >= len(self.events):
            return b""
        kind, data = self.events[self.index]
        if kind == "EOF":
            self.index += 1
            return None
        if kind != "RX":
            return b""
        chunk = data[self.offset:self.offset + size]
        self._advance(len(chunk))
        return chunk

    def left(self) -> int:
        """Recorded bytes not yet played."""
        return sum(len(data) for _, data in self.events[self.index:]) - self.offset


def parse_recording(text: str) -> list[Connection]:
    """The connections of a spy:// hexdump (our record:// adds OPEN and EOF lines)."""
    connections: list[Connection] = []
    for line in text.splitlines():
        fields = line.split(maxsplit=2)
        if len(fields) < 2:
            continue
        label = fields[1]
        if label == "OPEN" or (not connections and label in ("TX", "RX")):
            connections.append(Connection())
        if label in ("TX", "RX") and len(fields) > 2 and fields[2] != "<empty>":
            connections[-1].add(label, bytes.fromhex(line[HEX_COLUMNS]))
        elif label == "EOF":
            connections[-1].add("EOF")
    return connections


class ReplaySession:
    """A recording being replayed: its connections, one per open of replay://F."""

    def __init__(self, path: str) -> None:
        self.path = path
        try:
            self.connections = parse_recording(Path(path).read_text())
        except OSError as err:
            raise DeviceError(f"replay://{path}: cannot read the recording ({err.strerror})") from None
        self.opened = 0

    def next_connection(self) -> Connection | None:
        if self.opened >= len(self.connections):
            return None
        self.opened += 1
        return self.connections[self.opened - 1]

    def left(self) -> int:
        """Recorded bytes not played (in every connection)."""
        return sum(c.left() for c in self.connections)


_SESSIONS: dict[str, ReplaySession] = {}
_RECORDING: set[str] = set()  # files a record:// connection of this process has started
_LOCK = threading.Lock()


def replay_session(path: str) -> ReplaySession:
    """The session replaying `path` (started by its first open)."""
    key = str(Path(path).resolve())
    with _LOCK:
        if key not in _SESSIONS:
            _SESSIONS[key] = ReplaySession(path)
        return _SESSIONS[key]


def finish_replay(path: str | Path) -> ReplaySession:
    """End the replay of `path` (the next replay://path starts from the beginning) and return it, to check what
    was played: `left()` recorded bytes unplayed, `opened` of `len(connections)` connections."""
    key = str(Path(path).resolve())
    with _LOCK:
        return _SESSIONS.pop(key, None) or ReplaySession(str(path))


def start_recording(path: str) -> bool:
    """Whether this is the first connection of the process recording to `path` (which then starts it afresh)."""
    key = str(Path(path).resolve())
    with _LOCK:
        first = key not in _RECORDING
        _RECORDING.add(key)
        return first

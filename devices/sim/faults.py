"""The one fault injector of every device simulator: seeded, so a faulty run is reproducible.

Per frame a simulator sends (`FaultConfig.rate`, the kind drawn by `weights`): garbage bytes inside the frame,
a junk frame before it, the frame truncated, the frame dropped (the host times out), one byte corrupted, or
the device disappearing (the connection closed, refused for `down_s`, then back after a reset). A hostile device
does worse: it vanishes mid-frame (`vanish`: half the frame sent, then the connection closed), or keeps talking
instead of answering until the host sends again (at most `talk_s`): `stream` sends frames that are not the
answer (the device's `chatter`: status lines, answers under another id or address), `flood` bytes that never
end a frame (megabytes without a newline). Per command a
device obeys without answering (`ignore_rate`): the command ignored, which the host sees only by the device's
behaviour. `delay_s` makes every answer late. The bytes garbage and junk are made of are the framer's
(`devices.link.Noise`): printable text on a line protocol, any byte on a binary one. Counters say what was
injected.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from devices.link import Noise

FAULT_KINDS = ("garbage", "junk", "truncate", "drop", "disconnect", "corrupt", "vanish", "stream", "flood")
SERVER_KINDS = ("disconnect", "vanish", "stream", "flood")  # the server acts on these, not apply()


@dataclass
class FaultConfig:
    rate: float = 0.0  # probability that a frame the device sends is hit by a fault
    weights: dict[str, float] = field(default_factory=lambda: {
        "garbage": 0.35, "junk": 0.25, "truncate": 0.25, "drop": 0.12, "disconnect": 0.03})
    down_s: float = 0.03  # how long a vanished device refuses connections
    seed: int = 0
    ignore_rate: float = 0.0  # probability that a command the device obeys without answering is ignored
    delay_s: float = 0.0  # every answer is sent this late (a slow device)
    talk_s: float = 30.0  # how long a device that keeps talking (stream, flood) goes on while the host is silent
    talk_bytes_s: float = 16e6  # and how fast: far beyond a serial line, within what a host reads


class FaultInjector:
    """Draws the faults of one simulator: `stream` keeps simulators sharing a seed independent."""

    def __init__(self, config: FaultConfig, stream: int) -> None:
        unknown = set(config.weights) - set(FAULT_KINDS)
        if unknown:
            raise ValueError(f"unknown fault kinds {sorted(unknown)}: use {', '.join(FAULT_KINDS)}")
        self.config = config
        self.rng = np.random.default_rng([config.seed, stream, 99])
        kinds = [k for k in FAULT_KINDS if config.weights.get(k, 0) > 0]
        self.kinds = kinds
        weights = np.array([config.weights[k] for k in kinds], dtype=float)
        self.p = weights / weights.sum() if len(kinds) else weights
        self.counts: Counter[str] = Counter()

    def pick(self, allow_disconnect: bool = True) -> str | None:
        """A fault for the next frame sent, or None. Disconnects only before an answer's first frame (the
        device vanishes between exchanges, not inside one of its own bulk transfers)."""
        if self.config.rate <= 0 or self.rng.random() >= self.config.rate:
            return None
        kind = str(self.rng.choice(self.kinds, p=self.p))
        if kind in ("disconnect", "vanish") and not allow_disconnect:
            kind = "garbage"
        self.counts[kind] += 1
        return kind

    def ignores(self) -> bool:
        """Whether the device ignores the command it just received (drawn only when ignore_rate > 0)."""
        hit = self.config.ignore_rate > 0 and self.rng.random() < self.config.ignore_rate
        if hit:
            self.counts["ignore"] += 1
        return hit

    def apply(self, kind: str | None, data: bytes, noise: Noise, terminator: bytes) -> bytes:
        """The bytes sent for a frame `data` (without its terminator) hit by fault `kind` (None: none;
        SERVER_KINDS are the server's to act on)."""
        if kind == "drop":
            return b""
        if kind in SERVER_KINDS:
            raise ValueError(f"fault {kind!r} is the server's to act on, not a change of the frame's bytes")
        if kind == "garbage":
            data = self._garble(data, noise)
        elif kind == "truncate":
            data = data[: int(self.rng.integers(0, max(1, len(data))))]
        elif kind == "corrupt" and data:
            at = int(self.rng.integers(0, len(data)))
            data = data[:at] + bytes([data[at] ^ int(self.rng.integers(1, 256))]) + data[at + 1:]
        elif kind == "junk":
            return self.junk_frame(noise) + terminator + data + terminator
        return data + terminator

    def _garble(self, data: bytes, noise: Noise) -> bytes:
        junk = bytes(self.rng.integers(*noise.insert, int(self.rng.integers(1, 6))).astype(np.uint8))
        at = int(self.rng.integers(0, len(data) + 1))
        return data[:at] + junk + data[at:]

    def junk_frame(self, noise: Noise) -> bytes:
        return bytes(self.rng.integers(*noise.junk, int(self.rng.integers(*noise.junk_length))).astype(np.uint8))

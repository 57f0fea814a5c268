"""The device side of CRC lines with request ids (devices/crclines.py): what every such simulator does alike —
answer a damaged line with ERR 2 under the id it seems to carry, refuse lines without an id, turn a bad argument
into ERR 4 — so a simulator only says what its commands do (`dispatch`)."""

from __future__ import annotations

from abc import abstractmethod

from devices.crclines import CrcLineFramer, Damaged
from devices.sim.server import SimDevice


class TaggedLineSim(SimDevice):
    """A SimDevice speaking CRC lines with request ids; subclasses implement dispatch()."""

    framer = CrcLineFramer

    def chatter(self, answer: str) -> str:
        """The answer under id 0, which no host request carries (ids are 1..65535): a sound line that answers
        something else."""
        return "#0 " + answer.split(" ", 1)[-1]

    def handle(self, frame: str | Damaged) -> list[str]:
        if isinstance(frame, Damaged):
            words = frame.text.split()
            tag = words[0] if words and words[0].startswith("#") and words[0][1:].isdigit() else "#0"
            return [f"{tag} ERR 2 bad checksum"]
        words = frame.split()
        if len(words) < 2 or not words[0].startswith("#"):
            return ["#0 ERR 1 unknown command"]
        tag, command, args = words[0], words[1], words[2:]
        try:
            return self.dispatch(tag, command, args)
        except (ValueError, IndexError):
            return [f"{tag} ERR 4 bad argument"]

    @abstractmethod
    def dispatch(self, tag: str, command: str, args: list[str]) -> list[str]:
        """The answer lines (each starting with `tag`) to one sound request; ValueError/IndexError: ERR 4."""

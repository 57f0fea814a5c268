"""The wall scanner's sensor channels, in one registry: what each is called, sees and shows.

Every module that handles readings iterates over CHANNELS or looks a channel up by name (`by_name("ac")`,
or the constants INDUCTIVE, CAPACITIVE, AC) instead of spelling the names, so a new sensor (a radar, a
capacitive imager) is one more entry here. `name` is the key in scan logs, map files and JSON: never renamed.
The order is the scanner's: `index` is the column of a channel in the wall scanner's reading triple (counts)
and in scanner.sensor_model's simulated readings.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass


@dataclass(frozen=True)
class Channel:
    """One sensor channel of the wall scanner."""

    name: str  # key in logs, map files and JSON
    index: int  # column in the scanner's reading triple (counts) and the simulated readings
    label: str  # for plots and messages
    sees: str  # what it can tell, for messages: a point it did not cover may hide these
    # Object classes whose signal it shows (scanner.sensor_model): what explains its map
    responds_to: tuple[str, ...]
    # Object classes a stretch of which counts as measured where this channel covered it
    measures: tuple[str, ...]
    footprint_sigma_m: float  # its footprint's σ at the surface (scanner.sensor_model.SensorConfig's default)
    saturating: bool  # readings are the display's soft saturation 1 − exp(−raw), else linear
    two_sided: bool  # objects lower its level as well as raise it (cavities): a two-sided background
    safety: bool  # between them the safety channels show every object that matters (before drilling)
    line_peaks: bool  # its 1-D peaks along a pass locate pipes and cables (its footprint is narrow enough)
    cmap: str  # matplotlib colour map of its plots
    units: str = "display units"
    # Object classes no map may claim without this channel (a record lacking it names them less finely)
    needed_for: tuple[str, ...] = ()


INDUCTIVE = Channel(
    "inductive", 0, "inductive sensor", "metal (pipes, cables, screws, plates)",
    responds_to=("power_line", "metal_pipe", "metal", "fastener"),
    measures=("power_line", "metal_pipe", "metal", "fastener"),
    footprint_sigma_m=0.011, saturating=True, two_sided=False, safety=True, line_peaks=True, cmap="viridis",
    # a pipe and a fastener are found by their metal; "not metal" is the inductive channel's claim alone
    needed_for=("metal_pipe", "fastener", "non_metal"))
CAPACITIVE = Channel(
    "capacitive", 1, "capacitive sensor", "water-filled plastic pipes, wood and cavities",
    # screws and nails are too small to show capacitively
    responds_to=("power_line", "metal_pipe", "metal", "non_metal", "cavity"),
    measures=("non_metal", "cavity"),
    footprint_sigma_m=0.022, saturating=False, two_sided=True, safety=True, line_peaks=False, cmap="cividis",
    needed_for=("non_metal", "cavity"))
AC = Channel(
    "ac", 2, "AC sensor", "live cables",
    # only live cables and metal coupled to them
    responds_to=("power_line", "metal_pipe", "metal"),
    measures=("power_line",),
    footprint_sigma_m=0.004, saturating=True, two_sided=False, safety=False, line_peaks=True, cmap="magma",
    # only a live cable's crest tells a cable from a pipe: without it both are "metal"
    needed_for=("power_line", "metal_pipe"))

CHANNELS: tuple[Channel, ...] = (INDUCTIVE, CAPACITIVE, AC)  # in `index` order
NAMES: tuple[str, ...] = tuple(c.name for c in CHANNELS)
TWO_SIDED: tuple[str, ...] = tuple(c.name for c in CHANNELS if c.two_sided)
SAFETY: tuple[str, ...] = tuple(c.name for c in CHANNELS if c.safety)
LINE_PEAKS: tuple[Channel, ...] = tuple(c for c in CHANNELS if c.line_peaks)
_BY_NAME = {c.name: c for c in CHANNELS}
assert [c.index for c in CHANNELS] == list(range(len(CHANNELS))), "CHANNELS must be in index order"


def by_name(name: str) -> Channel:
    """The channel of that name (KeyError names the known ones)."""
    try:
        return _BY_NAME[name]
    except KeyError:
        raise KeyError(f"no sensor channel {name!r}; the scanner has {', '.join(NAMES)}") from None



def claimable(cls: str, channels: Iterable[str]) -> bool:
    """Whether a record with these channels (names) can tell an object of class cls: every channel the class
    needs (`needed_for`) is among them."""
    have = set(channels)
    return all(c.name in have for c in CHANNELS if cls in c.needed_for)

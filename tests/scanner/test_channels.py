"""The sensor-channel registry: in the scanner's order, true to the simulated sensors, and the one place the
channel names are spelled."""

from __future__ import annotations

import io
import tokenize
from pathlib import Path

import numpy as np
import pytest

from mapping.grid import SENSORS
from scanner.channels import CHANNELS, NAMES, TWO_SIDED, by_name
from scanner.log import SAMPLE_COLUMNS
from scanner.sensor_model import SensorConfig, SensorModel
from scanner.wall import Wall, WallObject

ROOT = Path(__file__).resolve().parents[2]
# devices/ is a library beside scanner and may not import it: the wall scanner's wire protocol names its
# reading triple itself (devices/wallscanner.py), in the same order.
SPELLED_HERE = {Path("scanner/channels.py"), Path("devices/wallscanner.py")}


def test_the_registry_is_in_the_scanners_order() -> None:
    assert [c.index for c in CHANNELS] == list(range(len(CHANNELS)))
    assert len(set(NAMES)) == len(NAMES)
    assert all(by_name(c.name) is c for c in CHANNELS)
    with pytest.raises(KeyError, match="inductive, capacitive, ac"):
        by_name("radar")
    # logs and grids carry every channel, under its registry name and in its order
    assert SENSORS == NAMES
    assert tuple(c for c in SAMPLE_COLUMNS if c in NAMES) == NAMES


def test_footprints_are_the_simulated_sensors() -> None:
    cfg = SensorConfig()
    assert by_name("inductive").footprint_sigma_m == cfg.ind_sigma_u_m
    assert by_name("capacitive").footprint_sigma_m == 2 * cfg.ind_sigma_u_m  # the capacitive footprint: twice
    assert by_name("ac").footprint_sigma_m == cfg.ac_sigma_m


def _readings_over(obj: WallObject) -> np.ndarray:
    """Noise-free raw readings (n, channels) along a line through the object's middle."""
    wall = Wall(1.0, 0.6, objects=[obj])
    x = np.linspace(0.05, 0.95, 361)
    xy = np.column_stack([x, np.full_like(x, 0.3)])
    return SensorModel(wall).raw(xy, np.tile([1.0, 0.0], (len(x), 1)))


def test_what_each_channel_responds_to_is_what_the_simulator_shows() -> None:
    screw = WallObject("screw", "s", 0.005, points_m=np.array([[0.5, 0.3]]), material="steel")
    cavity = WallObject("cavity", "c", 0.02, outline_m=np.array([[0.3, 0.2], [0.7, 0.2], [0.7, 0.4], [0.3, 0.4]]))
    shown = {"fastener": np.abs(_readings_over(screw)).max(axis=0),
             "cavity": _readings_over(cavity).min(axis=0)}
    for c in CHANNELS:
        assert (shown["fastener"][c.index] > 1e-3) == ("fastener" in c.responds_to), c.name
    # a cavity lowers the level of just the two-sided channels
    assert tuple(c.name for c in CHANNELS if shown["cavity"][c.index] < -1e-3) == TWO_SIDED


def spelled_names(source: str) -> list[tuple[int, str]]:
    """(line, literal) of each string literal in the source that is exactly a channel's name."""
    quoted = {f'"{n}"' for n in NAMES} | {f"'{n}'" for n in NAMES}
    return [(t.start[0], t.string) for t in tokenize.generate_tokens(io.StringIO(source).readline)
            if t.type == tokenize.STRING and t.string in quoted]


def test_no_product_module_spells_a_channel_name() -> None:
    files = [f for package in ("geometry", "scanner", "calibration", "wallpose", "render", "devices", "mapping",
                               "arproj") for f in sorted((ROOT / package).rglob("*.py"))]
    assert len(files) > 100
    found = [f"{f.relative_to(ROOT)}:{line}: {literal}" for f in files if f.relative_to(ROOT) not in SPELLED_HERE
             for line, literal in spelled_names(f.read_text(encoding="utf-8"))]
    assert not found, "look the channel up in scanner.channels instead:\n" + "\n".join(found)


def test_spelled_names_finds_a_made_up_literal() -> None:
    source = 'x = samples["ac"]\n"""the ac and "inductive" maps"""\ny = f"{k}_ac"\nz = samples[AC.name]\n'
    assert spelled_names(source) == [(1, '"ac"')]

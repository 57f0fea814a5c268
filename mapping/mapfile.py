"""objects.json as its readers see it: the mapped objects with their evidence (measured or inferred), depth and
uncertainty. `arproj map` writes it (mapping.exports); the drill check, the projection session and the report
read it here, so there is one reader and its checks.

    {"format": "arproj-objects/2", "frame": "wall", "units": "m",
     "objects": [{"class": "power_line", "kind": "line" | "point" | "outline", "points_m": [[x, y], …],
                  "width_m": w, "confidence": 0…1, "position_sigma_m": σ,
                  "depth_m": d | null, "depth_sigma_m": σ_d | null,
                  "measured": [true, false, …]}, …],
     "scanned_regions_m": [{"exterior": [[x, y], …], "holes": [[[x, y], …], …]}, …]}

`measured` has one entry per segment of a line (len(points_m) − 1) and one for a point or outline: true where
a sensor that sees that class covered the stretch, false where it was joined across unmeasured ground
(inferred). Files of format 1 (no `format` key) are read with every stretch measured; their scanned regions
are outer outlines only and are ignored: coverage comes from coverage.npz (mapping.evidence).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from geometry import provenance
from geometry.errors import InputError
from geometry.inputs import float_array, load_document, number

FORMAT = "arproj-objects/2"
FILE_NAME = "objects.json"
MAP_CLASSES = ("power_line", "metal_pipe", "metal", "fastener", "non_metal", "cavity")
# Classes drawn as closed outlines when a file does not say (format 1): a non-metal object (a wooden stud, or a
# water-filled plastic pipe: the capacitive channel cannot tell which) is an outline only when its points close
# a ring, else a line.
OUTLINE_CLASSES = ("non_metal", "cavity")
CLASS_ALIASES = {"wood": "non_metal"}  # names of earlier versions: "wood" was every raised capacitive region
# What a class claims, in words (legends, labels): only what the channels can tell
CLASS_LABELS = {"power_line": "power line", "metal_pipe": "metal pipe", "metal": "metal", "fastener": "fastener",
                "non_metal": "non-metal: stud or water pipe", "cavity": "cavity"}
SHAPES = ("line", "point", "outline")
DEFAULT_SIGMA_M = 0.003  # position σ of a mapped object when objects.json gives none (mapping's target)
MIN_CONFIDENCE_FOR_SIGMA = 0.25  # σ grows as 1/confidence, down to this confidence
MAX_OBJECTS = 100_000  # more is no map of one wall: refuse before allocating
MAX_POINTS = 1_000_000
MAX_FILE_BYTES = 256 * 2**20
OUTSIDE_MARGIN_M = 0.05  # how far past the wall's edge a mapped object may reach (a line's end, a band)


@dataclass
class MappedObject:
    """One mapped object in wall coordinates. points_m: (n, 2) float64, metres; measured: (segments,) bool
    (None: all measured)."""

    cls: str
    points_m: NDArray[np.float64]
    width_m: float
    confidence: float = 1.0
    sigma_m: float = DEFAULT_SIGMA_M
    depth_m: float | None = None
    depth_sigma_m: float | None = None
    measured: NDArray[np.bool_] | None = None
    shape: str | None = None  # line | point | outline; None: from the class and the number of points

    def __post_init__(self) -> None:
        self.points_m = np.asarray(self.points_m, dtype=np.float64).reshape(-1, 2)
        if self.shape is None:
            self.shape = ("point" if len(self.points_m) == 1 else
                          "outline" if self.cls in OUTLINE_CLASSES and _is_ring(self.cls, self.points_m) else
                          "line")

    @property
    def is_outline(self) -> bool:
        return self.shape == "outline"

    @property
    def n_segments(self) -> int:
        return max(len(self.points_m) - 1, 1) if self.shape == "line" else 1

    def measured_segments(self) -> NDArray[np.bool_]:
        if self.measured is None:
            return np.ones(self.n_segments, bool)
        return np.asarray(self.measured, dtype=bool)

    @property
    def fully_measured(self) -> bool:
        return bool(self.measured_segments().all())

    def parts(self, measured: bool) -> list[NDArray[np.float64]]:
        """The polylines (k, 2) of this line's measured (or inferred) stretches; a point or an outline is one
        part, whole."""
        flags = self.measured_segments()
        if self.shape != "line" or len(self.points_m) < 2:
            return [self.points_m] if bool(flags[0]) == measured else []
        out, run = [], None
        for k, flag in enumerate(flags):
            if bool(flag) == measured:
                run = [self.points_m[k]] if run is None else run
                run.append(self.points_m[k + 1])
            elif run is not None:
                out.append(np.array(run))
                run = None
        if run is not None:
            out.append(np.array(run))
        return out

    def to_json(self) -> dict:
        def opt(v: float | None, nd: int) -> float | None:
            return None if v is None or not math.isfinite(v) else round(float(v), nd)

        return {"class": self.cls, "kind": self.shape,
                "points_m": [[round(float(x), 5), round(float(y), 5)] for x, y in self.points_m],
                "width_m": round(float(self.width_m), 4), "confidence": round(float(self.confidence), 3),
                "position_sigma_m": round(float(self.sigma_m), 5),
                "depth_m": opt(self.depth_m, 4), "depth_sigma_m": opt(self.depth_sigma_m, 4),
                "measured": [bool(m) for m in self.measured_segments()]}


def _is_ring(cls: str, points: NDArray[np.float64]) -> bool:
    """Whether points (k, 2) of an outline class without a stated shape are an outline: a cavity with three
    or more points; a non-metal object when they also close (first point = last)."""
    if len(points) < 3:
        return False
    return cls != "non_metal" or bool(len(points) >= 4 and np.allclose(points[0], points[-1]))


def _finite_number(where: str, key: str, value: object, lo: float, hi: float) -> float:
    return number(where, key, value, lo, hi)


def _optional_number(where: str, key: str, value: object, lo: float, hi: float) -> float | None:
    return None if value is None else _finite_number(where, key, value, lo, hi)


def parse_object(item: object, where: str) -> MappedObject:
    if not isinstance(item, dict):
        raise InputError(f"{where} is not an object")
    cls = item.get("class")
    alias = CLASS_ALIASES.get(cls) if isinstance(cls, str) else None
    if alias is not None and item.get("kind") is None and isinstance(item.get("points_m"), list) \
            and len(item["points_m"]) >= 3:
        item = {**item, "kind": "outline"}  # a "wood" object was always a stud's or a beam's outline
    cls = alias or cls
    if cls not in MAP_CLASSES:
        raise InputError(f"{where}: class {cls!r} is unknown", f"use one of {', '.join(MAP_CLASSES)}")
    points = float_array(where, "points_m", item.get("points_m"), (None, 2), -1e3, 1e3, max_rows=MAX_POINTS,
                         unit="metres")
    if not len(points):
        raise InputError(f"{where}: points_m must be a list [[x, y], …] of 1 to {MAX_POINTS} points")
    if "width_m" not in item:
        raise InputError(f"{where}: key 'width_m' is missing")
    width = _finite_number(where, "width_m", item["width_m"], 0.0, 10.0)
    confidence = _finite_number(where, "confidence", item.get("confidence", 1.0), 0.0, 1.0)
    sigma = _optional_number(where, "position_sigma_m", item.get("position_sigma_m"), 0.0, 1.0)
    if sigma is None:
        sigma = DEFAULT_SIGMA_M / max(min(confidence, 1.0), MIN_CONFIDENCE_FOR_SIGMA)
    depth = _optional_number(where, "depth_m", item.get("depth_m"), 0.0, 1.0)
    depth_sigma = _optional_number(where, "depth_sigma_m", item.get("depth_sigma_m"), 0.0, 1.0)
    shape = item.get("kind")
    if shape is not None and shape not in SHAPES:
        raise InputError(f"{where}: kind {shape!r} is unknown", f"use one of {', '.join(SHAPES)}")
    obj = MappedObject(str(cls), points, float(width), float(confidence), float(sigma),
                       depth, depth_sigma, None, shape)
    measured = item.get("measured")
    if measured is not None:
        if not (isinstance(measured, list) and all(isinstance(m, bool) for m in measured)
                and len(measured) == obj.n_segments):
            raise InputError(f"{where}: measured must be a list of {obj.n_segments} true/false, one per segment")
        obj.measured = np.array(measured, dtype=bool)
    return obj


def read_objects(path: str | Path) -> list[MappedObject]:
    """objects.json → its objects; InputError names the file, the object and the problem."""
    path = Path(path)
    doc = load_document(path, "objects file", "pass the folder written by `arproj map … --out DIR`",
                        max_bytes=MAX_FILE_BYTES)
    if not isinstance(doc, dict) or not isinstance(doc.get("objects"), list):
        raise InputError(f"{path}: expected {{\"objects\": [...]}}")
    if doc.get("format", FORMAT) not in (FORMAT, "arproj-objects/1"):
        raise InputError(f"{path}: format {doc.get('format')!r} is not one this arproj reads ({FORMAT})")
    if len(doc["objects"]) > MAX_OBJECTS:
        raise InputError(f"{path}: {len(doc['objects'])} objects; a wall map has at most {MAX_OBJECTS}")
    return [parse_object(item, f"{path}: objects[{i}]") for i, item in enumerate(doc["objects"])]


def check_objects_within(objects: list[MappedObject], bounds: tuple[float, float, float, float],
                         path: str | Path, margin_m: float = OUTSIDE_MARGIN_M) -> None:
    """InputError when an object lies off the wall its map folder's coverage layer covers (bounds x0, y0, x1, y1,
    metres): objects.json from another wall's map."""
    x0, y0, x1, y1 = bounds
    for i, obj in enumerate(objects):
        p = obj.points_m
        outside = (p[:, 0] < x0 - margin_m) | (p[:, 0] > x1 + margin_m) | (p[:, 1] < y0 - margin_m) | \
            (p[:, 1] > y1 + margin_m)
        if outside.any():
            at = p[np.argmax(outside)].round(3).tolist()
            raise InputError(f"{path}: objects[{i}] ({obj.cls}) has a point at {at} m, off the mapped wall "
                             f"({x0:g}..{x1:g} x {y0:g}..{y1:g} m): objects.json from "
                             "another map?", "use the objects.json written with this map by `arproj map`")


def objects_document(objects: list[MappedObject], scanned_regions: list[dict] | None = None) -> dict:
    doc: dict = {"format": FORMAT, "made_by": provenance.record(), "frame": "wall", "units": "m",
                 "objects": [o.to_json() for o in objects]}
    if scanned_regions is not None:
        doc["scanned_regions_m"] = scanned_regions
    return doc


def write_objects(path: str | Path, objects: list[MappedObject], scanned_regions: list[dict] | None = None) -> Path:
    path = Path(path)
    path.write_text(json.dumps(objects_document(objects, scanned_regions), indent=1) + "\n")
    return path

"""Exports of a map, one module per file format (as trimesh's `exchange/`): wall.glb, objects.json,
coverage.npz, map.png, signals.png, objects.dxf, map_server.yaml (+ .pgm).

A format is a module here with `FILE_NAME` (what it writes into the map folder), `ORDER` (where `arproj map`
writes it; the projection session's wall.glb first) and `write(job: ExportJob) -> Path`. Adding a format is
adding such a module: `formats()` finds it. Each module's docstring describes its file.
"""

from __future__ import annotations

import functools
import importlib
import pkgutil
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import trimesh

from mapping.exports.common import ExportJob, scanned_regions
from mapping.pipeline import MapResult
from mapping.scandata import ScanData

__all__ = ["ExportJob", "export_all", "export_steps", "file_names", "formats", "scanned_regions"]

_NOT_FORMATS = {"common"}


def formats() -> list[ModuleType]:
    """Every format module of this package, in writing order."""
    found = [importlib.import_module(f"{__name__}.{m.name}") for m in pkgutil.iter_modules(__path__)
             if m.name not in _NOT_FORMATS]
    return sorted(found, key=lambda m: (m.ORDER, m.__name__))


def file_names() -> set[str]:
    """The names of every file the exports write into a map folder (a format writing more than one file lists
    the others in EXTRA_FILES)."""
    return {name for m in formats() for name in (m.FILE_NAME, *getattr(m, "EXTRA_FILES", ()))}


def export_steps(data: ScanData, result: MapResult, out_dir: str | Path, mesh: trimesh.Trimesh | None = None,
                 title: str = "", signal_y: float | None = None) -> list[tuple[str, Callable[[], Path]]]:
    """(file name, writer) for every export into out_dir, in the order `arproj map` writes them."""
    if result.coverage is None:
        raise ValueError("the map result has no coverage layer")
    job = ExportJob(data, result, Path(out_dir), mesh, title, signal_y)
    return [(m.FILE_NAME, functools.partial(m.write, job)) for m in formats()]


def export_all(data: ScanData, result: MapResult, out_dir: str | Path,
               mesh: trimesh.Trimesh | None = None) -> dict[str, Path]:
    """Every export into out_dir; returns {name: path}."""
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    return {name: write() for name, write in export_steps(data, result, out_dir, mesh)}

"""objects.json: the mapped objects (format arproj-objects/2, read by mapping.mapfile): class, shape, polyline,
width, confidence, position σ, depth and its σ, and per segment whether it was measured or inferred;
scanned_regions_m: the area both safety channels covered, as polygons with holes (for drawing only)."""

from __future__ import annotations

from pathlib import Path

from mapping import mapfile
from mapping.exports.common import ExportJob, scanned_regions

FILE_NAME = mapfile.FILE_NAME
ORDER = 20


def write(job: ExportJob) -> Path:
    return mapfile.write_objects(job.out_dir / FILE_NAME, job.objects, scanned_regions(job.result))

"""map_server.yaml + map_server.pgm: the drill verdicts as a ROS map_server occupancy map (trinary), for RViz,
Foxglove and nav2's map_server. Each cell holds check_point's verdict at its centre for an 8 mm bit in the wall
frame: free (254) where the safety channels looked and found nothing, occupied (0) inside a measured object's
safety band, unknown (205) everywhere else, including inferred stretches and ground nobody scanned.

The thresholds are chosen so that map_server's trinary reading (occ = (255 − value) / 255; occ > occupied_thresh
is occupied, occ < free_thresh free, else unknown) gives back exactly these three: 205 reads as occ 0.196, above
free_thresh 0.1, so unknown can never load as free (ROS 1's saver writes free_thresh 0.196, the very edge)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from geometry import provenance
from mapping import drill
from mapping.exports.common import ExportJob

FILE_NAME = "map_server.yaml"
IMAGE_NAME = "map_server.pgm"
EXTRA_FILES = (IMAGE_NAME,)
ORDER = 70

FREE, OCCUPIED, UNKNOWN = 254, 0, 205
OCCUPIED_THRESH, FREE_THRESH = 0.65, 0.1
_PIXEL = {drill.VERDICT_CODES[drill.SAFE]: FREE, drill.VERDICT_CODES[drill.KEEP_AWAY]: OCCUPIED,
          drill.VERDICT_CODES[drill.UNKNOWN]: UNKNOWN}


def write(job: ExportJob) -> Path:
    result = job.result
    if result.coverage is None:
        raise ValueError("the map result has no coverage layer")
    verdicts = drill.verdict_raster(job.objects, result.coverage, result.bounds)
    lut = np.full(256, UNKNOWN, np.uint8)
    for code, value in _PIXEL.items():
        lut[code] = value
    image = lut[verdicts.astype(np.uint8)][::-1]  # the image's first row is the grid's top (map_server's origin
    # is the lower-left pixel)
    info = result.coverage.info
    header = f"P5\n# arproj drill verdicts: free {FREE}, occupied {OCCUPIED}, unknown {UNKNOWN}\n" \
             f"{info.width} {info.height}\n255\n"
    (job.out_dir / IMAGE_NAME).write_bytes(header.encode("ascii") + np.ascontiguousarray(image).tobytes())
    doc = {"image": IMAGE_NAME, "mode": "trinary", "resolution": float(info.resolution),
           "origin": [float(info.origin_x), float(info.origin_y), 0.0], "negate": 0,
           "occupied_thresh": OCCUPIED_THRESH, "free_thresh": FREE_THRESH}
    path = job.out_dir / FILE_NAME
    path.write_text(f"# {provenance.line()}\n" + yaml.safe_dump(doc, sort_keys=False))
    return path

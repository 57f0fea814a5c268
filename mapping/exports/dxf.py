"""objects.dxf: one layer per class; LWPOLYLINE for lines and outlines, CIRCLE for fasteners, in millimetres
(CAD's habit)."""

from __future__ import annotations

from pathlib import Path

from geometry import provenance
from mapping import mapfile
from mapping.exports.common import ExportJob
from mapping.fusion import CLASSES

FILE_NAME = "objects.dxf"
ORDER = 60


def write(job: ExportJob) -> Path:
    return write_dxf(job.objects, job.out_dir / FILE_NAME)


def write_dxf(objects: list[mapfile.MappedObject], path: str | Path) -> Path:
    """objects.dxf: a layer per class (inferred stretches on CLASS_INFERRED, dashed), millimetres, wall frame
    (x right, y up); each object's depth in a text label beside it."""
    import ezdxf

    path = Path(path)
    doc = ezdxf.new(units=ezdxf.units.MM, setup=True)
    made_by = provenance.record()
    doc.header.custom_vars.append("ARPROJ_VERSION", made_by["version"])
    doc.header.custom_vars.append("ARPROJ_COMMAND", made_by["command"])
    msp = doc.modelspace()
    aci = {"power_line": 1, "metal_pipe": 5, "metal": 6, "non_metal": 30, "cavity": 4, "fastener": 2}
    for cls in CLASSES:
        doc.layers.add(cls.upper(), color=aci.get(cls, 7))
        doc.layers.add(f"{cls.upper()}_INFERRED", color=aci.get(cls, 7), linetype="DASHED")
    doc.layers.add("LABELS", color=7)
    for o in objects:
        layer = o.cls.upper() if o.cls in CLASSES else "0"
        if o.shape == "point":
            pts = [(float(x) * 1000.0, float(y) * 1000.0) for x, y in o.points_m]
            msp.add_circle(pts[0], radius=max(o.width_m, 0.004) * 500.0, dxfattribs={"layer": layer})
        for measured in (True, False):
            for part in ([] if o.shape == "point" else o.parts(measured)):
                pts = [(float(x) * 1000.0, float(y) * 1000.0) for x, y in part]
                closed = o.is_outline
                name = layer if measured or layer == "0" else f"{layer}_INFERRED"
                poly = msp.add_lwpolyline(pts[:-1] if closed and len(pts) > 3 else pts, dxfattribs={"layer": name})
                poly.closed = closed
                if o.shape == "line":
                    poly.dxf.const_width = o.width_m * 1000.0
        if o.depth_m is not None:
            sigma = "" if o.depth_sigma_m is None else f" ±{o.depth_sigma_m * 1000:.0f}"
            anchor = o.points_m[len(o.points_m) // 2] * 1000.0
            msp.add_text(f"{o.cls.replace('_', ' ')} {o.depth_m * 1000:.0f}{sigma} mm deep", height=12.0,
                         dxfattribs={"layer": "LABELS"}).set_placement((float(anchor[0]) + 15.0,
                                                                        float(anchor[1]) + 15.0))
    doc.saveas(path)
    return path

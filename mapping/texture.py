"""The in-wall map baked into an RGBA texture in wall coordinates, and applied to a wall-frame mesh.

Texture layout: the image covers the wall rectangle [x_min, x_max] × [y_min, y_max] (metres); its top row is
the highest y (as a person sees the wall), pixel (row, col) centre at
x = x_min + (col + 0.5)/px_per_m, y = y_max − (row + 0.5)/px_per_m. Texture coordinates follow trimesh/OpenGL:
u = (x − x_min)/(x_max − x_min), v = (y − y_min)/(y_max − y_min), v = 0 at the image's bottom row.

Colours: one per class (CLASS_COLOURS), alpha from the class probability. Alpha also marks coverage: alpha 0
exactly where the channels that rule objects out (mapping.evidence.SAFETY_CHANNELS) did not both cover the
wall (unknown), a faint neutral grey (alpha SCANNED_ALPHA) where they did and nothing was found. Measured
stretches of objects are drawn solid, inferred ones (joined across unmeasured ground) dashed.
"""

from __future__ import annotations

import cv2
import numpy as np
import trimesh
from numpy.typing import NDArray
from PIL import Image

from mapping.grid import GridInfo
from mapping.mapfile import MappedObject

CLASS_COLOURS: dict[str, tuple[int, int, int]] = {
    "power_line": (230, 30, 30),
    "metal_pipe": (30, 90, 230),
    "metal": (150, 60, 200),
    "non_metal": (190, 130, 50),  # a wooden stud or a water-filled plastic pipe
    "cavity": (40, 190, 190),
    "fastener": (240, 200, 0),
    "unknown": (128, 128, 128),
}
SCANNED_ALPHA = 24  # scanned, nothing found: faint grey; alpha 0 is reserved for "not scanned"
SCANNED_GREY = (200, 200, 200)
DASH_M = 0.02  # inferred stretches: 2 cm dashes with 2 cm gaps


def dashed_polyline(img: NDArray[np.uint8], pts: NDArray[np.float64], colour: tuple[int, ...], thickness: int,
                    dash_px: float) -> None:
    """Draw the polyline pts (k, 2) pixel coordinates as dashes of dash_px with equal gaps (in place)."""
    seg = np.diff(pts, axis=0)
    lengths = np.linalg.norm(seg, axis=1)
    s_start = np.concatenate([[0.0], np.cumsum(lengths)])
    total = float(s_start[-1])
    s = 0.0
    while s < total:
        a, b = s, min(s + dash_px, total)
        piece = [np.interp(a, s_start, pts[:, 0]), np.interp(a, s_start, pts[:, 1])]
        inner = [pts[k + 1] for k in range(len(seg)) if a < s_start[k + 1] < b]
        end = [np.interp(b, s_start, pts[:, 0]), np.interp(b, s_start, pts[:, 1])]
        poly = np.rint(np.array([piece, *inner, end]) * 4).astype(np.int32)  # 2 fractional bits for cv2
        cv2.polylines(img, [poly], False, colour, thickness, cv2.LINE_AA, shift=2)
        s += 2 * dash_px


def bake_texture(info: GridInfo, class_index: NDArray[np.int16], class_prob: NDArray[np.float64],
                 classes: list[str], known: NDArray[np.bool_], objects: list[MappedObject],
                 bounds: tuple[float, float, float, float], px_per_m: float = 500.0) -> NDArray[np.uint8]:
    """RGBA image (H, W, 4) of the map over bounds (x_min, y_min, x_max, y_max) metres.

    class_index (height, width): index into classes, −1 none; class_prob: its probability; known: scanned
    cells. Objects are drawn on top with their widths (lines), as dots (fasteners) and outlines.
    """
    x0, y0, x1, y1 = bounds
    W = max(2, round((x1 - x0) * px_per_m))
    H = max(2, round((y1 - y0) * px_per_m))
    xs = x0 + (np.arange(W) + 0.5) / px_per_m
    ys = y1 - (np.arange(H) + 0.5) / px_per_m
    cols = np.floor((xs - info.origin_x) / info.resolution).astype(int)
    rows = np.floor((ys - info.origin_y) / info.resolution).astype(int)
    in_c = (cols >= 0) & (cols < info.width)
    in_r = (rows >= 0) & (rows < info.height)
    rr, cc = np.meshgrid(np.clip(rows, 0, info.height - 1), np.clip(cols, 0, info.width - 1), indexing="ij")
    inside = in_r[:, None] & in_c[None, :]
    img = np.zeros((H, W, 4), np.uint8)
    kn = known[rr, cc] & inside
    img[kn] = (*SCANNED_GREY, SCANNED_ALPHA)
    idx = class_index[rr, cc]
    prob = class_prob[rr, cc]
    palette = np.array([CLASS_COLOURS.get(c, CLASS_COLOURS["unknown"]) for c in classes] + [(0, 0, 0)], np.uint8)
    hit = kn & (idx >= 0)
    img[hit, :3] = palette[idx[hit]]
    img[hit, 3] = np.clip(60 + 120 * np.nan_to_num(prob[hit]), 0, 255).astype(np.uint8)

    def to_px_float(p: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.column_stack([(p[:, 0] - x0) * px_per_m - 0.5, (y1 - p[:, 1]) * px_per_m - 0.5])

    def to_px(p: NDArray[np.float64]) -> NDArray[np.int32]:
        return np.rint(to_px_float(p) * 4).astype(np.int32)  # 2 fractional bits for cv2's shift

    for obj in objects:
        colour = (*CLASS_COLOURS.get(obj.cls, CLASS_COLOURS["unknown"]), 255)
        pts = to_px(obj.points_m)
        thick = max(2, round(max(obj.width_m, 0.008) * px_per_m))
        if obj.shape == "line":
            for part in obj.parts(measured=True):
                cv2.polylines(img, [to_px(part)], False, colour, thick, cv2.LINE_AA, shift=2)
            for part in obj.parts(measured=False):
                dashed_polyline(img, to_px_float(part), colour, thick, DASH_M * px_per_m)
        elif obj.shape == "point":
            cv2.circle(img, tuple(int(v) for v in pts[0]), max(3, round(0.006 * px_per_m)) * 4, colour, -1,
                       cv2.LINE_AA, shift=2)
        else:
            cv2.polylines(img, [pts], True, colour, max(2, round(0.004 * px_per_m)), cv2.LINE_AA, shift=2)
    return img


def textured_wall_mesh(mesh: trimesh.Trimesh, image: NDArray[np.uint8],
                       bounds: tuple[float, float, float, float]) -> trimesh.Trimesh:
    """The wall-frame mesh with UVs from its vertices' (x, y) over bounds and the RGBA image as texture."""
    x0, y0, x1, y1 = bounds
    v = np.asarray(mesh.vertices)
    uv = np.column_stack([(v[:, 0] - x0) / (x1 - x0), (v[:, 1] - y0) / (y1 - y0)])
    material = trimesh.visual.material.PBRMaterial(baseColorTexture=Image.fromarray(image, "RGBA"),
                                                   alphaMode="BLEND", doubleSided=True,
                                                   metallicFactor=0.0, roughnessFactor=1.0)
    out = trimesh.Trimesh(vertices=v.copy(), faces=np.asarray(mesh.faces).copy(), process=False)
    out.visual = trimesh.visual.TextureVisuals(uv=uv, material=material)
    return out

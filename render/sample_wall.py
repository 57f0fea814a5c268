"""A textured test wall for demos and benchmarks: a wall-sized mesh with gentle relief and a busy texture."""

from __future__ import annotations

import cv2
import numpy as np
import trimesh
from numpy.typing import NDArray
from PIL import Image

WALL_SIZE_M = (2.5, 2.0)
RELIEF_M = 0.002  # plaster is not flat: a couple of millimetres of waviness


def sample_wall_texture(size_px: int = 4096, wall_size_m: tuple[float, float] = WALL_SIZE_M) -> NDArray[np.uint8]:
    """(size_px, size_px, 4) RGBA: a 10 cm grid with labels, a fine checker border and a few 'pipes'."""
    w_m, h_m = wall_size_m
    img = np.full((size_px, size_px, 4), 255, dtype=np.uint8)
    img[..., :3] = (236, 232, 224)  # plaster

    def px(x_m: float, y_m: float) -> tuple[int, int]:
        # Texture row 0 is the top of the wall (y = height).
        return round(x_m / w_m * (size_px - 1)), round((1 - y_m / h_m) * (size_px - 1))

    line = max(1, size_px // 1024)
    for x in np.arange(0.0, w_m + 1e-9, 0.1):
        cv2.line(img, px(x, 0), px(x, h_m), (150, 150, 150, 255), line * (2 if round(x * 10) % 5 == 0 else 1))
    for y in np.arange(0.0, h_m + 1e-9, 0.1):
        cv2.line(img, px(0, y), px(w_m, y), (150, 150, 150, 255), line * (2 if round(y * 10) % 5 == 0 else 1))
    for x in np.arange(0.0, w_m - 0.05, 0.5):
        for y in np.arange(0.0, h_m - 0.05, 0.5):
            cv2.putText(img, f"x{x:.1f} y{y:.1f}", px(x + 0.015, y + 0.02), cv2.FONT_HERSHEY_SIMPLEX,
                        size_px / 4096 * 1.6, (60, 60, 60, 255), line * 3, cv2.LINE_AA)
    # Water pipe (blue), live cable (red), diagonal pipe (orange): what the product will draw.
    cv2.line(img, px(0.6, 0.0), px(0.6, h_m), (40, 90, 220, 255), size_px // 200)
    cv2.line(img, px(0.0, 1.25), px(w_m, 1.25), (220, 40, 40, 255), size_px // 300)
    cv2.line(img, px(1.2, 0.3), px(2.2, 1.3), (240, 140, 20, 255), size_px // 220)
    # Checker border: sharp edges everywhere, hard for texture filtering and easy to check by eye.
    sq = size_px // 64
    for i in range(64):
        for edge_y in (0, size_px - sq):
            if i % 2 == 0:
                img[edge_y:edge_y + sq, i * sq:(i + 1) * sq, :3] = 30
        for edge_x in (0, size_px - sq):
            if i % 2 == 1:
                img[i * sq:(i + 1) * sq, edge_x:edge_x + sq, :3] = 30
    return img


def sample_wall_mesh(grid: int = 318, texture_px: int = 4096, wall_size_m: tuple[float, float] = WALL_SIZE_M
                   ) -> trimesh.Trimesh:
    """The wall in its own frame (x right, y up, z into the room), grid × grid vertices, textured.

    The default grid gives 2·317² = 200,978 triangles.
    """
    w_m, h_m = wall_size_m
    u, v = np.meshgrid(np.linspace(0.0, 1.0, grid), np.linspace(0.0, 1.0, grid))
    x, y = u * w_m, v * h_m
    z = RELIEF_M * np.sin(2 * np.pi * x / 0.7) * np.sin(2 * np.pi * y / 0.9)
    vertices = np.column_stack([x.ravel(), y.ravel(), z.ravel()])
    idx = np.arange(grid * grid).reshape(grid, grid)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    faces = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    visual = trimesh.visual.TextureVisuals(uv=np.column_stack([u.ravel(), v.ravel()]),
                                           image=Image.fromarray(sample_wall_texture(texture_px, wall_size_m)))
    return trimesh.Trimesh(vertices=vertices, faces=faces, visual=visual, process=False)

"""Ground truth of the registration on the simulated site: where the drawn features really land.

A feature drawn for wall point w is rendered into the beamer frame at the session's belief of the projector
pose; its centroid in that frame is a physical projector pixel, and the simulated site's exact ray casting
(true intrinsics, true pose) says where on the wall that pixel lands. The distance to w is the true
registration error of what the person sees.
"""

from __future__ import annotations

import itertools
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from arproj.session import registration
from geometry.poses import invert, transform_points

if TYPE_CHECKING:
    from arproj.sim.protocols import SiteTruth

MARK_SEPARATION_RADII = 4.0   # marks in one frame: centres at least this many (summed) radii apart
MARK_RADIUS_PX = 2.5          # each mark covers at least this many projector pixels in radius
MIN_MARK_RADIUS_M = 0.004
FEATURE_STEP_M = 0.05          # registration error: map points every 5 cm along the mapped objects …
FEATURE_MARGIN = 0.05          # … inside the inner 90 % of the beamer image


def map_features(wall_map: object, T_wall_from_projector: NDArray[np.float64], intr: object) -> NDArray[np.float64]:
    """Wall points (n, 2) along the map's objects (every FEATURE_STEP_M; fasteners as they are; outlines
    closed) that the beamer at T_wall_from_projector shows inside the inner part of its image: where the
    registration error is measured. An empty map gives (0, 2)."""
    pts = []
    for obj in wall_map.objects:  # type: ignore[attr-defined]
        p = np.asarray(obj.points_m, dtype=np.float64)
        seq = np.concatenate([p, p[:1]]) if obj.is_outline else p
        if len(seq) == 1:
            pts.append(seq)
        for a, b in itertools.pairwise(seq):
            n = max(2, int(np.ceil(np.linalg.norm(b - a) / FEATURE_STEP_M)) + 1)
            pts.append(a + np.linspace(0.0, 1.0, n)[:, None] * (b - a))
    if not pts:
        return np.zeros((0, 2))
    pts = np.unique(np.round(np.concatenate(pts), 6), axis=0)
    cam = transform_points(invert(T_wall_from_projector), np.column_stack([pts, np.zeros(len(pts))]))
    _, inside = registration.project_in_view(intr, cam, margin=FEATURE_MARGIN)  # type: ignore[arg-type]
    return pts[inside]


def separated_passes(points_px: NDArray[np.float64], radii_px: NDArray[np.float64]) -> list[NDArray[np.int64]]:
    """Split marks into groups (indices) in which every two are MARK_SEPARATION_RADII·(r_i + r_j) apart."""
    remaining = list(range(len(points_px)))
    passes = []
    while remaining:
        chosen: list[int] = []
        rest = []
        for i in remaining:
            if all(np.linalg.norm(points_px[i] - points_px[j]) >= MARK_SEPARATION_RADII * (radii_px[i] + radii_px[j])
                   for j in chosen):
                chosen.append(i)
            else:
                rest.append(i)
        passes.append(np.array(chosen, dtype=np.int64))
        remaining = rest
    return passes


def _marks_in_view(T_wall_from_projector: NDArray[np.float64], intr: object, marks_xy: NDArray[np.float64]
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The marks (k, 2) the projector at T_wall_from_projector shows, their projector pixels (k, 2) and radii
    (metres, projector pixels): at least MARK_RADIUS_PX pixels, and MIN_MARK_RADIUS_M."""
    marks_xy = np.asarray(marks_xy, dtype=np.float64).reshape(-1, 2)
    p = transform_points(invert(T_wall_from_projector), np.column_stack([marks_xy, np.zeros(len(marks_xy))]))
    predicted, inside = registration.project_in_view(intr, p)  # type: ignore[arg-type]
    marks_xy, predicted = marks_xy[inside], predicted[inside]
    step = registration.rays_to_wall(T_wall_from_projector, intr,  # type: ignore[arg-type]
                                     np.concatenate([predicted, predicted + np.array([1.0, 0.0]),
                                                     predicted + np.array([0.0, 1.0])]))[:, :2]
    n = len(predicted)
    footprint = np.maximum(np.linalg.norm(step[n:2 * n] - step[:n], axis=1),
                           np.linalg.norm(step[2 * n:] - step[:n], axis=1))
    radius_m = np.maximum(MIN_MARK_RADIUS_M, MARK_RADIUS_PX * footprint)
    return marks_xy, predicted, radius_m, radius_m / footprint


def true_landing_errors(session: object, site: SiteTruth, marks_xy: NDArray[np.float64],
                        wall_index: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Render marks at marks_xy (n, 2) with the session's current pose — each a disc of at least
    MARK_RADIUS_PX projector pixels, drawn in passes of well separated marks — find their centroids in the
    rendered frame and ray-cast those projector pixels with the site's truth.

    Returns (errors (k,) metres, found projector pixels (k, 2)); marks not found or landing off the wall are
    left out.
    """
    reg = session.registration  # type: ignore[attr-defined]
    intr = session.projector_intr  # type: ignore[attr-defined]
    marks_xy, predicted, radius_m, radius_px = _marks_in_view(reg.T_wall_from_projector, intr, marks_xy)
    mp = session.map_projector  # type: ignore[attr-defined]
    errors, pixels = [], []
    for idx in separated_passes(predicted, radius_px):
        mp.set_check_marks(marks_xy[idx], radius_m[idx])
        frame = mp.render(reg.T_wall_from_projector)
        found = registration.find_marks(frame, predicted[idx], radius_px[idx])
        ok = np.all(np.isfinite(found), axis=1)
        truth = site.raycast("projector", found[ok])
        on_wall = np.asarray(truth.wall_index) == wall_index
        landed = np.asarray(truth.wall_xy, dtype=np.float64)[on_wall]
        errors.append(np.linalg.norm(landed - marks_xy[idx][ok][on_wall], axis=1))
        pixels.append(found[ok][on_wall])
    return np.concatenate(errors), np.concatenate(pixels)


def room_landing_errors(room_session: object, site: SiteTruth, k: int, marks_xy: NDArray[np.float64]
                        ) -> tuple[NDArray[np.float64], int]:
    """true_landing_errors for wall k of a RoomSession (arproj.session.room): the marks rendered on that wall
    alone with its correction, their centroids ray-cast with the site's truth. Returns (errors (m,) metres of
    the marks found — a mark that lands on another surface counts with its distance in the room —, how many
    landed on another surface than wall k)."""
    from arproj.session.projection import check_mark_raster
    from arproj.session.room import RoomSession

    assert isinstance(room_session, RoomSession)
    rs, w = room_session, room_session.walls[k]
    verdict = rs.verdicts[k]
    intr = rs.projector_intr
    T_room_from_projector = rs.T_room_from_projector
    assert T_room_from_projector is not None
    marks_xy, predicted, radius_m, radius_px = _marks_in_view(verdict.T_wall_from_projector, intr, marks_xy)
    errors: list[NDArray[np.float64]] = []
    wrong = 0
    for idx in separated_passes(predicted, radius_px):
        raster = check_mark_raster(w.wall_map, marks_xy[idx], radius_m[idx])
        rs.room_projector.show(("truth", k, marks_xy[idx].round(5).tobytes()), {k: raster},
                               {k: verdict.correction_xy})
        frame = rs.room_projector.render(T_room_from_projector)
        found = registration.find_marks(frame, predicted[idx], radius_px[idx])
        ok = np.all(np.isfinite(found), axis=1)
        truth = site.raycast("projector", found[ok])
        on_wall = np.asarray(truth.wall_index) == w.index
        landed = np.asarray(truth.wall_xy, dtype=np.float64)
        wanted = marks_xy[idx][ok]
        e = np.linalg.norm(landed - wanted, axis=1)
        room = transform_points(w.T_room_from_wall, np.column_stack([wanted, np.zeros(len(wanted))]))
        e[~on_wall] = np.linalg.norm(np.asarray(truth.points_room, dtype=np.float64)[~on_wall] - room[~on_wall],
                                     axis=1)
        errors.append(np.nan_to_num(e, nan=np.inf))
        wrong += int((~on_wall).sum())
    return (np.concatenate(errors) if errors else np.zeros(0)), wrong

"""The live view of a scan in Rerun (`arproj scan --view`): what the robot does and what the map learns, as it
happens, on the scan's own clock (timeline `scan_time`, seconds) and by pass (timeline `pass`).

Entities (2-D, wall metres, x along the wall, y up):
  wall/outline              the wall's rectangle
  wall/samples/<batch>      every pass's samples, coloured by the inductive reading (a batch: those sent at once)
  wall/coverage             the cells the safety channels covered so far (both: green, one: amber)
  wall/map/<channel>        the growing map of each channel: the mean reading in each cell so far (0..1 of
                            the display as 0..255), nothing where no sample fell
  wall/detections/<channel> the peaks the passes found along their course so far: where the adaptive plan
                            searched a pass, its own finds per channel (what it traces; scanner.run's `peaks`),
                            else (a channel it does not trace, a raster plan) the view's coarser search
  wall/robot                the robot's localised pose at each frame (the drive frame's origin and axes)
  wall/scanner              the scanner on the drives: where each pass sent since ended, the last one largest
Rerun's 2-D view draws y downwards: every position is sent as (x, top − y), so the wall stands upright.
Samples, detections and grids are sent every IMAGE_PERIOD_S of wall-clock time and at the end, so that a large
wall costs the scan little (a call to Rerun costs about a millisecond); the robot's pose at once. `FILE.rrd`
saves the recording (`rerun FILE.rrd` opens it); `live` spawns a viewer.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr
from numpy.typing import NDArray
from scipy import ndimage

from geometry.errors import InputError
from mapping.evidence import DEFAULT_COVERAGE_RADIUS_M, SAFETY_CHANNELS
from mapping.grid import GridInfo
from scanner.channels import AC, CAPACITIVE, INDUCTIVE
from scanner.channels import NAMES as CHANNEL_NAMES
from scanner.peaks import detect_peaks
from scanner.sim.world import FrameReport

IMAGE_PERIOD_S = 2.0
DETECTION_STEP_M = 0.004  # the view's peak search resamples a pass this finely (an eighth of the planner's work)
LIVE = "live"
ENTITIES = ("wall/outline", "wall/samples", "wall/coverage", *(f"wall/map/{c}" for c in CHANNEL_NAMES),
            *(f"wall/detections/{c}" for c in CHANNEL_NAMES), "wall/robot", "wall/scanner")
_DETECTION_COLOUR = {INDUCTIVE.name: (230, 60, 40), CAPACITIVE.name: (60, 120, 230), AC.name: (240, 200, 0)}


def check_target(view: str) -> None:
    """`--view` names `live` or a FILE.rrd whose folder exists (InputError otherwise)."""
    if view == LIVE:
        return
    path = Path(view)
    if path.suffix != ".rrd":
        raise InputError(f"--view {view}: give `live` (a viewer) or a FILE.rrd to save the recording")
    if not path.parent.is_dir():
        raise InputError(f"--view {view}: no folder {path.parent}", "create it first")


def open_recording(view: str, application_id: str) -> rr.RecordingStream:
    """A Rerun recording for `--view` (checked first): a spawned live viewer for "live", else saved to that
    .rrd file."""
    check_target(view)
    rec = rr.RecordingStream(application_id)
    if view == LIVE:
        rec.spawn()
    else:
        rec.save(view)
    return rec


class ScanView:
    """A scanner.run.ScanWatcher that streams the scan to Rerun."""

    def __init__(self, view: str, wall_width_m: float, wall_height_m: float, resolution_m: float = 0.005,
                 hysteresis_m: float = 0.0) -> None:
        """hysteresis_m: the inductive sensor's lag along the motion (the scan log's sensor), undone in the
        view's own search as the plan undoes it in its."""
        self.rec = open_recording(view, "arproj_scan")
        self.hysteresis_m = hysteresis_m
        self.info = GridInfo.covering(0.0, 0.0, wall_width_m, wall_height_m, resolution_m)
        self.top = self.info.origin_y + self.info.height * self.info.resolution
        self.sums = {c: np.zeros(self.info.shape) for c in CHANNEL_NAMES}
        self.counts = {c: np.zeros(self.info.shape) for c in CHANNEL_NAMES}
        # the pictures sent, kept between sends and redrawn only where samples fell since (the window `_dirty`,
        # rows and columns [r0, r1) × [c0, c1)): a large wall's grids cost what a pass touches, not the wall
        self.covered = {c: np.zeros(self.info.shape, bool) for c in SAFETY_CHANNELS}
        self.cover = np.zeros((*self.info.shape, 4), np.uint8)
        self.maps = {c: np.zeros((*self.info.shape, 4), np.uint8) for c in CHANNEL_NAMES}
        self._dirty: tuple[int, int, int, int] | None = None
        self._disks = {c: _disk(DEFAULT_COVERAGE_RADIUS_M[c] / self.info.resolution) for c in SAFETY_CHANNELS}
        self._images_sent = False
        self.passes = 0
        self._pending: list[tuple[NDArray[np.float64], NDArray[np.uint8]]] = []
        self._batches = 0
        self._ends: list[NDArray[np.float64]] = []
        self.found: dict[str, list[NDArray[np.float64]]] = {c: [] for c in CHANNEL_NAMES}
        self._new_found = False
        self._sent = time.monotonic()
        corners = np.array([[0, 0], [wall_width_m, 0], [wall_width_m, wall_height_m], [0, wall_height_m], [0, 0]])
        self.rec.log("wall/outline", rr.LineStrips2D([self._screen(corners)]), static=True)
        scale = rr.Transform3D(scale=[self.info.resolution, self.info.resolution, 1.0],
                               translation=[self.info.origin_x, 0.0, 0.0])
        for entity in ("wall/coverage", *(f"wall/map/{c}" for c in CHANNEL_NAMES)):
            self.rec.log(entity, scale, static=True)  # pixels to wall metres

    def _screen(self, xy: Any) -> NDArray[np.float64]:
        p = np.array(xy, dtype=np.float64).reshape(-1, 2)
        p[:, 1] = self.top - p[:, 1]
        return p

    def _at(self, t_s: float) -> None:
        self.rec.set_time("scan_time", duration=float(t_s))
        self.rec.set_time("pass", sequence=self.passes)

    def frame(self, row: dict[str, Any], report: FrameReport | None = None) -> None:
        self._at(row["time_s"])
        x, y, phi = float(row["est_x_m"]), float(row["est_y_m"]), float(row["est_phi_rad"])
        c, s = np.cos(phi), np.sin(phi)
        axes = [self._screen([[x, y], [x + 0.1 * c, y + 0.1 * s]]), self._screen([[x, y], [x - 0.1 * s, y + 0.1 * c]])]
        self.rec.log("wall/robot", rr.LineStrips2D(axes, colors=[(255, 0, 0), (0, 200, 0)],
                                                   labels=[f"frame {int(row['frame_id'])}", ""]))

    def scanned(self, row: dict[str, Any], samples: dict[str, NDArray[Any]]) -> None:
        self.passes += 1
        times = np.asarray(samples["time_s"], dtype=np.float64)
        if len(times) == 0:
            return
        self._at(times[0])
        xy = np.column_stack([samples["x_m"], samples["y_m"]])
        ind = np.nan_to_num(np.asarray(samples.get(INDUCTIVE.name, np.zeros(len(xy))), dtype=np.float64))
        level = np.clip(ind, 0.0, 1.0)
        colours = np.column_stack([255 * level, 80 + 100 * (1 - level), 255 * (1 - level)]).astype(np.uint8)
        self._pending.append((self._screen(xy), colours))
        rows, cols, inside = self.info.cell_of(xy)
        if inside.any():
            r, c = rows[inside], cols[inside]
            r0, r1, c0, c1 = box = (int(r.min()), int(r.max()) + 1, int(c.min()), int(c.max()) + 1)
            d = self._dirty or box
            self._dirty = (min(d[0], r0), max(d[1], r1), min(d[2], c0), max(d[3], c1))
            # summed by bincount over the pass's box (a pass runs along a row or a column: a thin box), which
            # costs a tenth of np.add.at over the whole grid
            width, cells = c1 - c0, (r1 - r0) * (c1 - c0)
            for channel in CHANNEL_NAMES:
                values = np.asarray(samples.get(channel, np.full(len(xy), np.nan)), dtype=np.float64)
                ok = inside & np.isfinite(values)
                flat = (rows[ok] - r0) * width + (cols[ok] - c0)
                window = np.s_[r0:r1, c0:c1]
                self.sums[channel][window] += np.bincount(flat, values[ok], cells).reshape(r1 - r0, width)
                self.counts[channel][window] += np.bincount(flat, minlength=cells).reshape(r1 - r0, width)
        self._detections(row, samples, xy)
        self._ends.append(self._screen(xy[-1]))
        if time.monotonic() - self._sent >= IMAGE_PERIOD_S:
            self.images()

    def _detections(self, row: dict[str, Any], samples: dict[str, NDArray[Any]], xy: NDArray[np.float64]) -> None:
        axis = row.get("axis")
        if axis not in ("x", "y"):  # a following pass runs along an object: its readings have no crossing
            return
        coord = np.asarray(samples["drive_u_m" if axis == "x" else "drive_v_m"], dtype=np.float64)
        order = np.argsort(coord)
        planned = row.get("peaks") or {}  # the plan's own search of the pass, where it made one
        for channel in CHANNEL_NAMES:
            if channel in planned:
                at = np.asarray(planned[channel], dtype=np.float64)
            else:
                values = np.asarray(samples.get(channel, ()), dtype=np.float64)
                if len(values) != len(coord) or not np.isfinite(values).all():
                    continue
                lag = self.hysteresis_m * float(row["direction"]) if channel == INDUCTIVE.name else 0.0
                at = np.array([p.position - lag for p in detect_peaks(coord, values, grid_step_m=DETECTION_STEP_M)])
            if not len(at):
                continue
            found = np.column_stack([np.interp(at, coord[order], xy[order, 0]),
                                     np.interp(at, coord[order], xy[order, 1])])
            self.found[channel].append(self._screen(found))
            self._new_found = True

    def _redraw(self) -> None:
        """Bring the pictures up to date inside the window samples fell in since the last send: each channel's
        mean reading (grey, unseen cells transparent) and the safety channels' coverage, the cells within the
        channel's coverage radius of a cell a sample fell in (the view's picture of coverage, a cell coarser than
        the map's, mapping.evidence.Coverage, which the drill check reads). Coverage only grows: the dilation
        is redone on the window widened by the radius (the cells it reaches), from the seen cells within twice
        the radius (all that reach them), which gives what dilating the whole grid gives."""
        if self._dirty is None:
            return
        r0, r1, c0, c1 = self._dirty
        self._dirty = None
        window = np.s_[r0:r1, c0:c1]
        for channel in CHANNEL_NAMES:
            counts = self.counts[channel][window]
            seen = counts > 0
            mean = np.divide(self.sums[channel][window], counts, out=np.zeros(counts.shape), where=seen)
            image = self.maps[channel][window]
            image[..., :3] = np.clip(255 * mean, 0, 255)[..., None]
            image[..., 3] = 255 * seen
        height, width = self.info.shape
        reach = max(len(disk) // 2 for disk in self._disks.values())
        out = np.s_[max(r0 - reach, 0):min(r1 + reach, height), max(c0 - reach, 0):min(c1 + reach, width)]
        a0, b0 = max(r0 - 2 * reach, 0), max(c0 - 2 * reach, 0)
        source = np.s_[a0:min(r1 + 2 * reach, height), b0:min(c1 + 2 * reach, width)]
        crop = np.s_[out[0].start - a0:out[0].stop - a0, out[1].start - b0:out[1].stop - b0]
        for channel, disk in self._disks.items():
            grown = ndimage.binary_dilation(self.counts[channel][source] > 0, structure=disk)
            self.covered[channel][out] |= grown[crop]
        covered = [self.covered[c][out] for c in SAFETY_CHANNELS]
        cover = self.cover[out]
        cover[...] = 0
        cover[np.any(covered, axis=0)] = (240, 170, 0, 120)  # one safety channel looked: amber
        cover[np.all(covered, axis=0)] = (0, 170, 60, 120)  # both: green

    def images(self) -> None:
        """Send what came since the last time: the samples (one entity per batch, so that every sample stays in
        view), every detection so far, the grids as they stand (flipped: an image's first row is the wall's
        top), those only if samples fell since. Batched, because each call to Rerun costs about a millisecond
        whatever it carries."""
        self._sent = time.monotonic()
        if self._pending:
            xy, colours = (np.concatenate(parts) for parts in zip(*self._pending, strict=True))
            self.rec.log(f"wall/samples/{self._batches}", rr.Points2D(xy, colors=colours, radii=0.0015))
            self._batches += 1
            self._pending = []
        if self._ends:  # where the scanner ended each pass since, the last one largest
            ends = np.concatenate(self._ends)
            self.rec.log("wall/scanner", rr.Points2D(ends, radii=[0.004] * (len(ends) - 1) + [0.01],
                                                     colors=[(0, 0, 0)]))
            self._ends = []
        if self._new_found:
            for channel, found in self.found.items():
                if found:
                    self.rec.log(f"wall/detections/{channel}", rr.Points2D(np.concatenate(found), radii=0.006,
                                                                          colors=[_DETECTION_COLOUR[channel]]))
            self._new_found = False
        if self._dirty is None and self._images_sent:
            return
        self._redraw()
        self._images_sent = True
        self.rec.log("wall/coverage", rr.Image(self.cover[::-1]))
        for channel in CHANNEL_NAMES:
            self.rec.log(f"wall/map/{channel}", rr.Image(self.maps[channel][::-1]))

    def close(self) -> None:
        self.images()
        self.rec.flush()
        self.rec.disconnect()


def _disk(radius: float) -> NDArray[np.bool_]:
    """The cells within `radius` cells of the centre one (a cell counts if its centre lies within radius + ½)."""
    r = int(np.ceil(radius))
    dy, dx = np.mgrid[-r:r + 1, -r:r + 1]
    return np.hypot(dx, dy) <= radius + 0.5


SESSION_ENTITIES = ("projector/frame", "projector/check_marks", "cameras/left", "cameras/right", "gate")


class SessionView:
    """The projection session in Rerun (`arproj project --view`), by cycle (timeline `cycle`): the frame shown
    (projector/frame), the closed loop's check marks in it (projector/check_marks: seen green, missed red), the
    cameras' last captures (cameras/left, cameras/right) and the gate's state (gate, a text log)."""

    def __init__(self, view: str, captures: Any) -> None:
        self.captures = captures
        self.rec = open_recording(view, "arproj_project")
        self.cycles = 0

    def cycle(self, session: Any, decision: Any) -> None:
        from arproj.session.record import gate_state
        from arproj.session.registration import project_in_view
        from geometry.poses import invert, transform_points

        self.rec.set_time("cycle", sequence=self.cycles)
        self.cycles += 1
        if session.last_frame is not None:
            self.rec.log("projector/frame", rr.Image(session.last_frame))
        reg = session.registration
        if reg is not None and reg.loop is not None and len(reg.loop.marks_xy):
            marks = np.c_[reg.loop.marks_xy, np.zeros(len(reg.loop.marks_xy))]
            uv = project_in_view(session.projector_intr, transform_points(invert(reg.T_wall_from_projector),
                                                                          marks))[0]
            colours = np.where(reg.loop.seen[:, None], [[0, 200, 0]], [[230, 40, 40]])
            self.rec.log("projector/check_marks", rr.Points2D(uv, colors=colours, radii=4.0))
        if self.captures.last is not None:
            left, right = self.captures.last
            self.rec.log("cameras/left", rr.Image(left))
            self.rec.log("cameras/right", rr.Image(right))
        self.rec.log("gate", rr.TextLog(gate_state(decision), level="INFO" if decision.show_map else "WARN"))

    def close(self) -> None:
        self.rec.flush()
        self.rec.disconnect()


CALIBRATION_ENTITIES = ("projector/pattern", "cameras/left", "cameras/right", "cameras/left/coverage",
                        "cameras/right/coverage")


class CalibrationView:
    """The live calibration in Rerun (`arproj calibrate projector --live --view`), by capture (timeline
    `capture`): the image shown (projector/pattern), each camera's frame (cameras/left, cameras/right) and the
    coverage, every board corner found so far in each camera's board views, drawn over its frames
    (cameras/left/coverage, cameras/right/coverage): where the image is still bare, the calibration has not
    looked."""

    def __init__(self, view: str) -> None:
        self.rec = open_recording(view, "arproj_calibrate")
        self.captures = 0
        self.corners: dict[str, list[NDArray[np.float64]]] = {"left": [], "right": []}

    def captured(self, image: NDArray[np.uint8], frames: tuple[NDArray[np.uint8], ...]) -> None:
        self.rec.set_time("capture", sequence=self.captures)
        self.captures += 1
        self.rec.log("projector/pattern", rr.Image(image))
        for side, frame in zip(("left", "right"), frames, strict=False):
            self.rec.log(f"cameras/{side}", rr.Image(frame))

    def boards(self, left: list[Any], right: list[Any]) -> None:
        """Board views found (calibration.boards.BoardView, None where the board was not found)."""
        for side, views in (("left", left), ("right", right)):
            found = [v.image_points for v in views if v is not None]
            if found:
                self.corners[side] += found
                self.rec.log(f"cameras/{side}/coverage", rr.Points2D(np.concatenate(self.corners[side]),
                                                                      colors=[(0, 200, 60)], radii=2.0))

    def close(self) -> None:
        self.rec.flush()
        self.rec.disconnect()

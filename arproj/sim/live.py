"""The simulated site as live devices, served from one process: a virtual screen, two cameras, the head, a laser.

What a live calibration talks to on hardware — a beamer showing frames, two cameras streaming pictures, a
Pelco-D head on a serial port, a 2-D laser — is served here on 127.0.0.1 from one simulated site:

    screen        tcp://127.0.0.1:P          frames in: 4-byte big-endian length + PNG; answer b"ok\\n" (or
                                             b"error: …\\n") once the frame is the projector's next image
    camera_left   http://127.0.0.1:Q/left.mjpg    multipart/x-mixed-replace; boundary=frame, image/jpeg parts
    camera_right  http://127.0.0.1:Q/right.mjpg   (what cv2.VideoCapture(url, cv2.CAP_FFMPEG) opens)
    head          socket://127.0.0.1:R       the Pelco-D head simulator (devices/sim), as PanTiltHead opens it
    laser         http://127.0.0.1:Q/laser.json   one scan: angles_rad, ranges_m (null: no return),
                                             T_robot_from_laser
    laser2d       socket://127.0.0.1:S       the same laser in the 2-D laser's line protocol (devices/laser2d.py,
                                             one head H), as `arproj project --laser` reads it on hardware
    inclinometer  socket://127.0.0.1:T       the robot's inclinometer (devices/inclinometer.py): the robot's true
                                             roll and pitch on the site's floor, its bias and noise on top
    board         http://127.0.0.1:Q/board/next?plan=stereo|wall|mount   the site's "person" puts the printed
                                             board at its next pose (stereo: held in front of both cameras as
                                             the wizard's simulated station does; wall: in the beam before the
                                             wall, tilted; mount: at the top of a tall panel standing on the
                                             floor across the laser's plane);
                                             /board/clear takes it away
    truth         http://127.0.0.1:Q/truth.json   the simulated truth (for tests and the benchmark only)

Each camera frame is rendered when it is sent, from the state at that moment: the last screen frame (shown
`display_latency_s` after it arrived, as a beamer shows a frame late), the head where the head simulator
physically is (moves draw the drive's bias, noise and backlash once per move), the board. Streams are paced at
`fps` and sent through a small socket buffer, so a client that stops reading finds only a frame or two queued
(the client must still drop them and wait for stable frames, as with a real camera). The site is owned by one
worker thread (its GL context is bound to it); everything else asks that thread.

    python -m arproj.sim.live [--seed N] [--small]    prints one JSON line of URLs (and projector_size),
                                                      serves until stdin closes (SpawnedLiveSite starts it)
    serve_live_site(seed=0) → LiveSite (urls, close()): the same in this process (for `arproj devices serve`)

By default the site is the calibration station's (the robot 2 m before the default room's wall, the stereo
mount off its drawing); `scene` gives Site.build's section overrides instead, e.g. the projection site
`arproj project --sim --site` builds around a scanned wall (arproj.site_file.simulated_projection_scene), so
that the same site runs in one process and served.
"""

from __future__ import annotations

import contextlib
import json
import queue
import socket
import socketserver
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any
from urllib.parse import parse_qs, urlparse

import cv2
import numpy as np
from numpy.typing import NDArray

from calibration.boards import parse_board
from calibration.defaults import DEFAULT_BOARD
from devices.sim import DeviceServer, HeadFaults, HeadSimulator, InclinometerSim
from geometry.poses import invert, make_pose, roll_pitch, rotation_about
from scanner.sim.devices import BufferedLaserSim

DEFAULT_FPS = 20.0
DISPLAY_LATENCY_S = 0.05  # a beamer shows a frame a little after it was sent
STREAM_SNDBUF_BYTES = 16384  # small: a stalled reader finds at most about one frame queued
JPEG_QUALITY = 95
HEAD_SYNC_S = 0.01  # how often the worker follows the head simulator's physical angles
CLOSE_WAIT_S = 10.0  # SpawnedLiveSite.close: how long the site may take to end once its stdin is closed,
TERMINATE_WAIT_S = 5.0  # and then after SIGTERM, before it is killed
# The stereo pair as mounted is off its drawing by this (σ per axis, in the robot frame) and this: what the mount
# calibration has to find; the build tolerance it assumes (calibration.laser_mount.DESIGN_SIGMA_*) is the same.
MOUNT_ERROR_DEG = 0.5
MOUNT_ERROR_M = 0.005
SMALL = {"cameras": {"width": 640, "height": 400}, "projector": {"width": 320, "height": 200}}
BOARD = DEFAULT_BOARD  # the printed board the site's person holds (the one the wizard asks for)
PANEL_HEIGHT_M = 1.5  # the mount plan's panel: the board printed at the top of a tall panel on the floor
MAX_FRAME_BYTES = 64 * 1024 * 1024
STEREO_PLAN_POSES = 48
# The mount plan's panel poses (pose k: distance k mod 3, lean (k div 3) mod 3, yaw k mod 5, each jittered).
MOUNT_PLAN_DISTANCES_M = (1.35, 1.55, 1.75)
MOUNT_PLAN_LEANS_DEG = (0.0, 12.0, 24.0)
MOUNT_PLAN_YAWS_DEG = (-25.0, 0.0, 25.0, 12.0, -12.0)


@dataclass
class LiveSiteUrls:
    screen: str
    camera_left: str
    camera_right: str
    head: str
    laser: str
    laser2d: str
    board: str
    truth: str
    inclinometer: str

    def as_dict(self) -> dict[str, str]:
        return dict(self.__dict__)


class LiveSite:
    """The simulated site served as devices (see the module docstring). Close it (or use `with`)."""

    def __init__(self, seed: int = 0, small: bool = False, fps: float = DEFAULT_FPS,
                 display_latency_s: float = DISPLAY_LATENCY_S, distance_m: float = 2.0,
                 mount_error: tuple[float, float] = (MOUNT_ERROR_DEG, MOUNT_ERROR_M),
                 scene: dict[str, Any] | None = None, head_faults: HeadFaults | None = None) -> None:
        self.seed, self.small, self.fps, self.display_latency_s = seed, small, fps, display_latency_s
        self.scene = scene
        self._jobs: queue.Queue[tuple[Callable[[Any], Any], queue.Queue]] = queue.Queue()
        self._stopping = threading.Event()
        self._ready: queue.Queue[BaseException | None] = queue.Queue()
        self._worker = threading.Thread(target=self._work, args=(distance_m, mount_error), daemon=True,
                                        name="live-site")
        self._worker.start()
        failure = self._ready.get()
        if failure is not None:
            raise failure
        self._board_poses = {"wall": 0, "mount": 0, "stereo": 0}
        self._rng = np.random.default_rng(seed + 2000)
        from arproj.wizard.sim_station import board_pose_plan

        self._stereo_plan = board_pose_plan(parse_board(BOARD), STEREO_PLAN_POSES, self._rng)
        self.head_sim = HeadSimulator(seed=seed, faults=head_faults,
                                      initial_deg=(float(self._aim[0]), float(self._aim[1])))
        self._http = ThreadingHTTPServer(("127.0.0.1", 0), _handler(self))
        self._http.daemon_threads = True
        self._screen = _ScreenServer(self)
        self._laser2d = DeviceServer(LiveLaserSim(self), stream=LIVE_LASER_STREAM)
        self._laser2d.start()
        self._inclinometer = InclinometerSim(self.true_tilt_deg, seed=seed)
        for server in (self._http, self._screen):
            threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True).start()
        http = f"http://127.0.0.1:{self._http.server_address[1]}"
        self.urls = LiveSiteUrls(screen=f"tcp://127.0.0.1:{self._screen.server_address[1]}",
                                 camera_left=f"{http}/left.mjpg", camera_right=f"{http}/right.mjpg",
                                 head=self.head_sim.url, laser=f"{http}/laser.json",
                                 laser2d=self._laser2d.url, board=f"{http}/board",
                                 truth=f"{http}/truth.json", inclinometer=self._inclinometer.url)

    # -- the worker that owns the site ------------------------------------------------------------------
    def _work(self, distance_m: float, mount_error: tuple[float, float]) -> None:
        from arproj.sim.site import Site

        try:
            if self.scene is not None:  # the given site, the robot placed as its scene says
                site = Site.build(seed=self.seed, **self.scene)
            else:
                cameras = {**SMALL["cameras"]} if self.small else {}
                cameras.update(mount_error_deg=mount_error[0], mount_error_m=mount_error[1])
                projector = SMALL["projector"] if self.small else {}
                site = Site.build(seed=self.seed, cameras=cameras, projector=projector)
                site.place_robot(distance_m, 0.0)
            p = site.projector
            # The head starts aimed so that the projected image's centre (not the optical axis, which lens
            # shift moves off the image) is in the cameras' view, as the wizard's simulated station aims it.
            shift_deg = np.degrees(np.arctan((p.cy - (p.height - 1) / 2) / p.fy))
            self._aim = site.head_angles_cmd_deg.copy() + np.array([0.0, -shift_deg, 0.0])
            self._aim[2] = 0.0  # a Pelco-D head has no roll axis: it stays at 0
            site.set_head(self._aim)
            self._projector_size = p.size
            self._screen_now = np.zeros((p.height, p.width), np.uint8)
            self._screen_next: tuple[float, NDArray[np.uint8]] | None = None
            self._synced: tuple[float, float] | None = None
        except BaseException as err:  # the caller re-raises it
            self._ready.put(err)
            return
        self._ready.put(None)
        try:
            while not self._stopping.is_set():
                try:
                    job, answer = self._jobs.get(timeout=HEAD_SYNC_S)
                except queue.Empty:
                    self._sync_head(site)
                    continue
                try:
                    self._sync_head(site)
                    answer.put((True, job(site)))
                except Exception as err:  # handed to the asking thread
                    answer.put((False, err))
        finally:
            site.release()

    def _sync_head(self, site: Any) -> None:
        """The site's head follows where the head simulator physically is; each change is a move of the drive
        (its noise and backlash drawn then, once), as SimulatedRobot.sync_head does for the session."""
        if not hasattr(self, "head_sim"):
            return
        true = self.head_sim.true_deg()
        if self._synced is None or not np.allclose(true, self._synced, atol=1e-9):
            site.set_head([true[0], true[1], 0.0])
            self._synced = true

    def call(self, job: Callable[[Any], Any]) -> Any:
        """Run job(site) on the worker thread and return its result (or raise its exception)."""
        answer: queue.Queue = queue.Queue(maxsize=1)
        self._jobs.put((job, answer))
        ok, value = answer.get()
        if not ok:
            raise value
        return value

    # -- what the servers ask ---------------------------------------------------------------------------
    @property
    def projector_size(self) -> tuple[int, int]:
        return self._projector_size

    def show(self, image: NDArray[np.uint8]) -> None:
        """A frame arrived at the screen: the projector shows it display_latency_s from now."""
        def job(site: Any) -> None:
            self._promote()
            self._screen_next = (time.monotonic() + self.display_latency_s, image)
        self.call(job)

    def _promote(self) -> None:
        if self._screen_next is not None and time.monotonic() >= self._screen_next[0]:
            self._screen_now = self._screen_next[1]
            self._screen_next = None

    def photograph(self, camera: str) -> NDArray[np.uint8]:
        def job(site: Any) -> NDArray[np.uint8]:
            self._promote()
            return site.photograph(camera, projector_image=self._screen_now).image
        return self.call(job)

    def laser_scan(self) -> dict:
        scan = self.call(lambda site: site.laser_scan())
        return {"angles_rad": scan.angles_rad.tolist(),
                "ranges_m": [float(r) if np.isfinite(r) else None for r in scan.ranges_m],
                "T_robot_from_laser": scan.T_robot_from_laser.tolist()}

    def true_tilt_deg(self) -> tuple[float, float]:
        """The robot's true (roll, pitch) on the site's floor, degrees (what its inclinometer measures)."""
        roll, pitch = self.call(lambda site: roll_pitch(site.T_room_from_robot))
        return float(np.degrees(roll)), float(np.degrees(pitch))

    def next_board(self, plan: str) -> dict:
        """The person puts the board at the plan's next pose."""
        if plan not in self._board_poses:
            raise ValueError(f"unknown board plan {plan!r} (stereo, wall, mount)")
        k = self._board_poses[plan]
        self._board_poses[plan] += 1
        jitter = self._rng.uniform(-1.0, 1.0, 4)
        stereo = self._stereo_plan[k % len(self._stereo_plan)]
        self.call(lambda site: _place_board(site, plan, k, jitter, stereo))
        return {"plan": plan, "pose": k}

    def clear_board(self) -> None:
        self.call(lambda site: site.remove_targets())

    def truth(self) -> dict:
        def job(site: Any) -> dict:
            drive = site._drive
            # Noise-free true minus commanded angles for angles approached from below (backlash: half of it
            # short of the target, in the direction of the last move), as the head plan approaches them.
            direction = np.where(drive._last_direction != 0, drive._last_direction, 1.0)
            direction[:2] = 1.0
            offset = drive.bias_deg - direction * drive.backlash_deg / 2.0
            return {
                "camera_left": _intrinsics(site.camera_left), "camera_right": _intrinsics(site.camera_right),
                "projector": _intrinsics(site.projector),
                "T_camera_right_from_camera_left": site.T_camera_right_from_camera_left.tolist(),
                "T_robot_from_camera_left": site.T_robot_from_camera_left.tolist(),
                "T_robot_from_camera_left_design": site.T_robot_from_camera_left_design.tolist(),
                "head": site.head.to_dict(), "head_angle_offset_deg": offset.tolist(),
                "aim_deg": self._aim.tolist(), "board": BOARD,
            }
        return self.call(job)

    # -- life -------------------------------------------------------------------------------------------
    def close(self) -> None:
        for server in (self._http, self._screen):
            server.shutdown()
            server.server_close()
        self._laser2d.stop()
        self._inclinometer.close()
        self.head_sim.close()
        self._stopping.set()
        self._worker.join(timeout=5.0)

    def __enter__(self) -> LiveSite:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def serve_live_site(seed: int = 0, small: bool = False, **options: Any) -> LiveSite:
    """The simulated site's devices on 127.0.0.1 (see LiveSite); `urls` says where. Close it when done."""
    return LiveSite(seed=seed, small=small, **options)


def _intrinsics(intr: Any) -> dict:
    return {"fx": intr.fx, "fy": intr.fy, "cx": intr.cx, "cy": intr.cy, "width": intr.width,
            "height": intr.height, "dist": list(intr.dist)}


# -- the board the site's person holds ------------------------------------------------------------------------

def _place_board(site: Any, plan: str, k: int, jitter: NDArray[np.float64],
                 T_camera_from_board_stereo: NDArray[np.float64]) -> None:

    board = parse_board(BOARD)
    pps = 48
    texture = board.render(pixels_per_square=pps, margin_squares=1.0)
    sq = board.square_m
    width_m, height_m = texture.shape[1] / pps * sq, texture.shape[0] / pps * sq
    site.remove_targets()
    T_room_from_left = site.T_room_from("camera_left")
    if plan == "stereo":  # held in front of both cameras as the wizard's simulated station holds it
        T_board_from_texture = make_pose(None, [-2 * sq, -2 * sq, 0.0])
        site.add_target(texture, (width_m, height_m), T_room_from_left @ T_camera_from_board_stereo
                        @ T_board_from_texture)
        return
    if plan == "wall":
        # In the beam, 85 % of the way to where the projected image's centre lands, turned in turn about
        # both axes by 20-30° (a flat board at one orientation cannot fix the projector's focal length).
        p = site.projector
        landing = site.raycast("projector", np.array([[(p.width - 1) / 2, (p.height - 1) / 2]])).points_room[0]
        centre = (invert(T_room_from_left) @ np.append(landing, 1.0))[:3] * 0.85
        tilts = [(0, 0), (25, 0), (-25, 0), (0, 22), (0, -22), (18, 18), (-18, -18), (18, -18), (-18, 18)]
        yaw, pitch = tilts[k % len(tilts)]
        R = (rotation_about([0, 1, 0], np.radians(yaw + 3 * jitter[0]))
             @ rotation_about([1, 0, 0], np.radians(pitch + 3 * jitter[1]))
             @ rotation_about([0, 0, 1], np.radians(6 * jitter[2])))
        T_cam_from_texture = make_pose(R, centre - R @ np.array([width_m / 2, height_m / 2, 0.0]))
        site.add_target(texture, (width_m, height_m), T_room_from_left @ T_cam_from_texture)
        return
    # mount: the board at the top of a tall white panel standing on the floor in front of the robot, leaning
    # back and turned, so that the cameras see the board and the laser's plane cuts the panel lower down.
    panel = np.full((round(PANEL_HEIGHT_M / sq * pps), texture.shape[1]), 255, np.uint8)
    panel[:texture.shape[0]] = texture
    distances, leans, yaws = MOUNT_PLAN_DISTANCES_M, MOUNT_PLAN_LEANS_DEG, MOUNT_PLAN_YAWS_DEG
    x0 = distances[k % len(distances)] + 0.05 * jitter[0]
    lean = np.radians(leans[(k // len(distances)) % len(leans)] + 2 * jitter[1])
    yaw = np.radians(yaws[k % len(yaws)] + 3 * jitter[2])
    forward = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    right = np.array([np.sin(yaw), -np.cos(yaw), 0.0])  # the viewer's right
    up = np.cos(lean) * np.array([0.0, 0.0, 1.0]) + np.sin(lean) * forward
    bottom = np.array([x0, 0.1 + 0.1 * jitter[3], 0.0])
    origin = bottom + PANEL_HEIGHT_M * up - width_m / 2 * right  # the print's top-left corner
    T_robot_from_panel = make_pose(np.column_stack([right, -up, np.cross(right, -up)]), origin)
    site.add_target(panel, (width_m, PANEL_HEIGHT_M), site.T_room_from_robot @ T_robot_from_panel)


# -- servers ------------------------------------------------------------------------------------------------

LIVE_LASER_STREAM = 6  # its fault stream (scanner/sim/devices.py has 1, 2, 4, 5; the head 3)
LIVE_LASER_HEAD = "H"  # the projection robot's one laser head, horizontal


class LiveLaserSim(BufferedLaserSim):
    """The site's 2-D laser in the 2-D laser's line protocol (devices/laser2d.py): one head, H; each SCAN is a
    fresh sweep of the site's laser (site.laser_scan, its noise drawn then), as a real laser's is."""

    model = "SIM-SITE 1.0"

    def __init__(self, live: LiveSite) -> None:
        super().__init__()
        self.live = live

    @property
    def heads(self) -> tuple[str, ...]:
        return (LIVE_LASER_HEAD,)

    def take(self, head: str, tag: int) -> tuple[NDArray[np.float64], float, float]:
        scan = self.live.call(lambda site: site.laser_scan())
        ranges = np.where(np.isfinite(scan.ranges_m), scan.ranges_m, np.nan)
        return ranges, float(scan.angles_rad[0]), float(scan.angles_rad[1] - scan.angles_rad[0])


def _handler(live: LiveSite) -> type[BaseHTTPRequestHandler]:
    class Handler(BaseHTTPRequestHandler):
        protocol_version = "HTTP/1.0"

        def log_message(self, format: str, *args: Any) -> None:
            return

        def do_GET(self) -> None:
            url = urlparse(self.path)
            try:
                if url.path in ("/left.mjpg", "/right.mjpg"):
                    self._stream("camera_left" if url.path == "/left.mjpg" else "camera_right")
                elif url.path == "/laser.json":
                    self._json(live.laser_scan())
                elif url.path == "/board/next":
                    self._json(live.next_board(parse_qs(url.query).get("plan", ["wall"])[0]))
                elif url.path == "/board/clear":
                    live.clear_board()
                    self._json({"cleared": True})
                elif url.path == "/truth.json":
                    self._json(live.truth())
                else:
                    self.send_error(404, "no such device")
            except (BrokenPipeError, ConnectionResetError):
                return
            except ValueError as err:
                self.send_error(400, str(err))

        def _json(self, doc: dict) -> None:
            body = json.dumps(doc).encode()
            self.send_response(200)
            self.send_header("Content-Type", "application/json")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def _stream(self, camera: str) -> None:
            self.connection.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, STREAM_SNDBUF_BYTES)
            self.send_response(200)
            self.send_header("Content-Type", "multipart/x-mixed-replace; boundary=frame")
            self.send_header("Cache-Control", "no-cache")
            self.end_headers()
            period = 1.0 / live.fps
            next_at = time.monotonic()
            while not live._stopping.is_set():
                delay = next_at - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                next_at = max(next_at + period, time.monotonic())
                ok, jpeg = cv2.imencode(".jpg", live.photograph(camera), [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
                if not ok:
                    return
                data = jpeg.tobytes()
                self.wfile.write(b"--frame\r\nContent-Type: image/jpeg\r\nContent-Length: "
                                 + str(len(data)).encode() + b"\r\n\r\n" + data + b"\r\n")
                self.wfile.flush()

    return Handler


class _ScreenServer(socketserver.ThreadingTCPServer):
    """The virtual screen: frames as length-prefixed PNG, each answered once the projector has it."""

    daemon_threads = True
    allow_reuse_address = True

    def __init__(self, live: LiveSite) -> None:
        self.live = live
        super().__init__(("127.0.0.1", 0), _ScreenHandler)


class _ScreenHandler(socketserver.StreamRequestHandler):
    server: _ScreenServer

    def handle(self) -> None:
        live = self.server.live
        while True:
            header = self.rfile.read(4)
            if len(header) < 4:
                return
            (length,) = struct.unpack(">I", header)
            if length > MAX_FRAME_BYTES:
                self.wfile.write(b"error: frame too large\n")
                return
            data = self.rfile.read(length)
            image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE)
            w, h = live.projector_size
            if image is None:
                reply = b"error: not a PNG image\n"
            elif image.shape != (h, w):
                reply = f"error: frame is {image.shape[1]}x{image.shape[0]}, the projector is {w}x{h}\n".encode()
            else:
                live.show(image)
                reply = b"ok\n"
            with contextlib.suppress(OSError):
                self.wfile.write(reply)
                self.wfile.flush()


def main(argv: list[str] | None = None) -> None:
    """Serve until stdin closes (the parent process ended) or SIGTERM; print the URLs as one JSON line."""
    import argparse
    import sys

    parser = argparse.ArgumentParser(prog="python -m arproj.sim.live", description=__doc__.split("\n")[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--small", action="store_true", help="640x400 cameras, a 320x200 projector (quick)")
    parser.add_argument("--fps", type=float, default=DEFAULT_FPS)
    args = parser.parse_args(argv)
    with serve_live_site(seed=args.seed, small=args.small, fps=args.fps) as live:
        print(json.dumps(live.urls.as_dict() | {"projector_size": list(live.projector_size)}), flush=True)
        with contextlib.suppress(KeyboardInterrupt):
            sys.stdin.read()  # returns when the parent closes our stdin (or ends)


if __name__ == "__main__":
    main()


class SpawnedLiveSite:
    """`python -m arproj.sim.live` in its own process (what `--sim` of the live commands starts): urls, projector
    size, and close() (closes its stdin, which ends it; terminated if it does not end)."""

    def __init__(self, seed: int = 0, small: bool = False, fps: float = DEFAULT_FPS) -> None:
        import subprocess
        import sys

        cmd = [sys.executable, "-m", "arproj.sim.live", "--seed", str(seed), "--fps", str(fps)]
        if small:
            cmd.append("--small")
        self.process = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        assert self.process.stdout is not None
        line = self.process.stdout.readline()
        if not line:
            self.process.wait(timeout=10)
            raise RuntimeError(f"the simulated site did not start (exit status {self.process.returncode})")
        doc = json.loads(line)
        self.projector_size = tuple(int(v) for v in doc.pop("projector_size"))
        self.urls = LiveSiteUrls(**doc)

    def truth(self) -> dict:
        import urllib.request

        with urllib.request.urlopen(self.urls.truth, timeout=30) as reply:
            return json.loads(reply.read())

    def close(self) -> None:
        import subprocess

        if self.process.stdin is not None:
            with contextlib.suppress(OSError):
                self.process.stdin.close()
        try:
            self.process.wait(timeout=CLOSE_WAIT_S)
        except subprocess.TimeoutExpired:
            self.process.terminate()
            try:
                self.process.wait(timeout=TERMINATE_WAIT_S)
            except subprocess.TimeoutExpired:  # a loaded machine: the calibration it served is done, so end it
                self.process.kill()
                self.process.wait()

    def __enter__(self) -> SpawnedLiveSite:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

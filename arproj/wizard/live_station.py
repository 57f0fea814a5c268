"""The calibration station on real devices: the beamer (a window on a display, or a screen over the network), one
or two cameras (an index, a file or a stream URL), the Pelco-D head at a serial URL, optionally a 2-D laser.

It offers what the wizard's steps use (steps.Station): project(image) shows the image, waits `settle_s` for the
beamer and the exposure, and takes from every camera the first frame that arrived after that and that the next
frame agrees with, and after a change of the scene (a new image, the board moved) that differs from the previous
capture's frame (calibration.capture.LiveCamera: a late frame from before the change is never taken);
command_head approaches every angle from below, as the head plan assumes; board_views asks the person to put the
board somewhere new each time (on the simulated site its "person" is a URL that moves the board: `BoardMover`).
"""

from __future__ import annotations

import json
import time
import urllib.error
import urllib.request
from collections.abc import Callable
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from arproj.session.output import FrameOutput, open_screen
from arproj.sim.site import LaserScan
from calibration.boards import Board, BoardView, detect
from calibration.capture import SETTLE_TIMEOUT_S, LiveCamera, open_source
from devices.pelco_d import PanTiltHead
from geometry.errors import InputError

SETTLE_S = 0.15  # a beamer shows a frame one or two refreshes late, and the camera exposes for a while
HEAD_APPROACH_DEG = 2.0  # every commanded angle is approached from below: backlash is the same each time
DEVICE_TIMEOUT_S = 10.0


class BoardMover(Protocol):
    def place(self, plan: str, instruction: str) -> None:
        """Put the board at its next pose for this plan (wall, mount, stereo), as the instruction says."""
        ...

    def clear(self, instruction: str) -> None:
        """Take the board away (out of the cameras' view and the projector's beam)."""
        ...


class PersonMover:
    """A person moves the board: say what to do and wait for Enter."""

    def __init__(self, ask: Callable[[str], str] = input) -> None:
        self.ask = ask

    def place(self, plan: str, instruction: str) -> None:
        del plan
        self.ask(f"{instruction}, then press Enter ")

    def clear(self, instruction: str) -> None:
        self.ask(f"{instruction}, then press Enter ")


class UrlMover:
    """The simulated site's person: GET URL/next?plan=PLAN moves the board (arproj.sim.live)."""

    def __init__(self, url: str) -> None:
        self.url = url.rstrip("/")

    def place(self, plan: str, instruction: str) -> None:
        del instruction
        fetch_json(f"{self.url}/next?plan={plan}", "the board mover")

    def clear(self, instruction: str) -> None:
        del instruction
        fetch_json(f"{self.url}/clear", "the board mover")


def fetch_json(url: str, what: str) -> dict:
    try:
        with urllib.request.urlopen(url, timeout=DEVICE_TIMEOUT_S) as reply:
            return json.loads(reply.read())
    except (urllib.error.URLError, OSError, json.JSONDecodeError) as err:
        raise InputError(f"{what} at {url}: {getattr(err, 'reason', err)}", "check the URL and that it runs"
                         ) from None


class LiveStation:
    """Real (or served) devices as a calibration station. Close it (or use `with`)."""

    def __init__(self, output: FrameOutput, projector_size: tuple[int, int], cameras: list[LiveCamera],
                 head: PanTiltHead | None = None, mover: BoardMover | None = None, laser_url: str | None = None,
                 settle_s: float = SETTLE_S, settle_timeout_s: float = SETTLE_TIMEOUT_S) -> None:
        self.output, self.projector_size, self.cameras, self.head = output, projector_size, cameras, head
        self.mover: BoardMover = mover or PersonMover()
        self.laser_url = laser_url
        self.settle_s, self.settle_timeout_s = settle_s, settle_timeout_s
        w, h = projector_size
        self.black = np.zeros((h, w), np.uint8)
        self.captures = 0
        self._shown: NDArray[np.uint8] | None = None  # the image shown for the last capture ...
        self._previous: list[NDArray[np.uint8]] | None = None  # ... and the frames taken of it
        self._scene_changed = False
        if head is not None:
            pan, tilt = head.position()
            self.aim_deg = np.array([pan, tilt, 0.0])  # where the person aimed the head (at the wall)
        else:
            self.aim_deg = np.zeros(3)

    @classmethod
    def open(cls, screen: str, projector_size: tuple[int, int], left: str, right: str | None = None,
             head_url: str | None = None, mover: BoardMover | None = None, laser_url: str | None = None,
             settle_s: float = SETTLE_S, settle_timeout_s: float = SETTLE_TIMEOUT_S) -> LiveStation:
        """Open the screen (--screen N or tcp://…), the cameras and the head; everything is closed again when
        one of them fails."""
        opened: list = []
        try:
            output = open_screen(screen, *projector_size)
            opened.append(output)
            cameras = []
            for source, name in ((left, "camera_left"), (right, "camera_right")):
                if source is not None:
                    cameras.append(LiveCamera(open_source(source, name), name))
                    opened.append(cameras[-1])
            head = PanTiltHead(head_url, timeout_s=0.5, settle_timeout_s=30.0) if head_url else None
            if head is not None:
                opened.append(head)
            return cls(output, projector_size, cameras, head, mover, laser_url, settle_s, settle_timeout_s)
        except BaseException:
            for device in reversed(opened):
                device.close()
            raise

    def close(self) -> None:
        for device in (*self.cameras, self.head, self.output):
            if device is not None:
                device.close()

    def __enter__(self) -> LiveStation:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- what the steps use ------------------------------------------------------------------------------
    def before_change(self) -> None:
        """Remember what the cameras see now, before the scene changes (the board is moved): the next capture
        takes only frames that differ from it (calibration.capture: frames that arrive late)."""
        if self._previous is None:
            self._previous = [cam.latest(self.settle_timeout_s) for cam in self.cameras]
        self._scene_changed = True

    def capture(self, image: NDArray[np.uint8]) -> list[NDArray[np.uint8]]:
        """Show image, let it settle, and one settled frame from every camera (grey). After a change (another
        image than last time, or before_change), each frame must differ from the previous capture's."""
        changed = self._scene_changed or self._shown is None or not np.array_equal(image, self._shown)
        reference = self._previous if changed else None
        self.output.show(image)
        after = time.monotonic() + self.settle_s
        self.captures += 1
        frames = [cam.settled_frame(after, self.settle_timeout_s, None if reference is None else reference[i])
                  for i, cam in enumerate(self.cameras)]
        self._shown, self._previous, self._scene_changed = image.copy(), frames, False
        return frames

    def project(self, image: NDArray[np.uint8]) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
        frames = self.capture(image)
        if len(frames) != 2:
            raise InputError("this step needs both cameras", "give --right CAM too")
        return frames[0], frames[1]

    def command_head(self, angles_deg: NDArray[np.float64]) -> None:
        """Move the head to these absolute (pan, tilt, roll) angles, arriving from below; roll must be 0 (a
        Pelco-D head has no roll axis)."""
        if self.head is None:
            raise InputError("this step turns the head", "give --head URL (e.g. /dev/ttyUSB0 or socket://…)")
        a = np.asarray(angles_deg, dtype=np.float64)
        if abs(a[2]) > 1e-9:
            raise InputError(f"head roll {a[2]:.2f}° asked of a pan/tilt head", "plan with roll 0")
        self.head.move_to(a[0] - HEAD_APPROACH_DEG, a[1] - HEAD_APPROACH_DEG)
        self.head.move_to(a[0], a[1])

    def clear_board(self) -> None:
        """The board away: nothing stands in the beam before the wall (the next capture waits for the change)."""
        self.before_change()
        self.mover.clear("take the board away: nothing may stand in the projector's beam or the cameras' view")

    def board_views(self, board: Board, n: int, plan: str = "stereo",
                    instruction: str = "hold the board somewhere new in front of both cameras, tilted"
                    ) -> tuple[list[BoardView | None], list[BoardView | None]]:
        """n views of the printed board (room light only: the beamer shows black), one per placement."""
        left: list[BoardView | None] = []
        right: list[BoardView | None] = []
        for k in range(n):
            self.before_change()
            self.mover.place(plan, f"board pose {k + 1}/{n}: {instruction}")
            frames = self.capture(self.black)
            left.append(detect(board, frames[0], source=f"live board pose {k:02d} camera_left"))
            right.append(detect(board, frames[1], source=f"live board pose {k:02d} camera_right")
                         if len(frames) > 1 else None)
        return left, right

    def laser_points(self) -> NDArray[np.float64]:
        """One laser scan as (n, 3) robot-frame points, from a JSON endpoint {angles_rad, ranges_m (null: no
        return), T_robot_from_laser} (the simulated site's; for a real laser, a bridge serving its scans)."""
        if self.laser_url is None:
            raise InputError("the mount step needs the laser", "give --laser URL")
        doc = fetch_json(self.laser_url, "the laser")
        try:
            angles = np.asarray(doc["angles_rad"], dtype=np.float64)
            ranges = np.array([np.inf if r is None else r for r in doc["ranges_m"]], dtype=np.float64)
            T = np.asarray(doc["T_robot_from_laser"], dtype=np.float64).reshape(4, 4)
        except (KeyError, TypeError, ValueError):
            raise InputError(f"the laser at {self.laser_url}: expected JSON with angles_rad, ranges_m and "
                             "T_robot_from_laser") from None
        return LaserScan(angles, ranges, T).points_robot()

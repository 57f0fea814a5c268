"""Where frames go: the beamer (a borderless fullscreen window on a chosen display, or a screen reached over the
network, such as the simulated site's), and files.

Every output takes RGB frames (h, w, 3) uint8 at the projector's resolution. A person-fixable problem — no
display, a display whose size is not the projector's — is an InputError saying what to do; the session then
keeps running with the file output.
"""

from __future__ import annotations

import contextlib
import os
import socket
import struct
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np
from numpy.typing import NDArray

from geometry.errors import InputError


class FrameOutput(Protocol):
    def show(self, frame: NDArray[np.uint8]) -> None: ...

    def close(self) -> None: ...


def as_rgb(frame: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """(h, w) grey or (h, w, 3) RGB → contiguous (h, w, 3) RGB uint8 (patterns are grey, maps are colour)."""
    frame = np.asarray(frame)
    if frame.ndim == 2:
        frame = np.repeat(frame[:, :, None], 3, axis=2)
    if frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8:
        raise ValueError(f"a beamer frame must be (h, w) or (h, w, 3) uint8, got {frame.shape} {frame.dtype}")
    return np.ascontiguousarray(frame)


class FileOutput:
    """Writes each frame as DIR/frame_00000.png, … (for recording and tests); keeps the last in memory."""

    def __init__(self, folder: str | Path, prefix: str = "frame") -> None:
        self.folder = Path(folder)
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise InputError(f"{self.folder}: cannot create the frame folder ({err.strerror})") from None
        self.prefix = prefix
        self.count = 0
        self.last: NDArray[np.uint8] | None = None
        self.paths: list[Path] = []

    def show(self, frame: NDArray[np.uint8]) -> None:
        frame = as_rgb(frame)
        path = self.folder / f"{self.prefix}_{self.count:05d}.png"
        if not cv2.imwrite(str(path), cv2.cvtColor(np.ascontiguousarray(frame), cv2.COLOR_RGB2BGR)):
            raise InputError(f"{path}: could not write the frame", "check free space and permissions")
        self.last = frame
        self.paths.append(path)
        self.count += 1

    def close(self) -> None:
        pass


class MemoryOutput:
    """Keeps the frames shown (the simulated beamer reads the last one)."""

    def __init__(self, keep: int = 1) -> None:
        self.keep = keep
        self.frames: list[NDArray[np.uint8]] = []

    @property
    def last(self) -> NDArray[np.uint8] | None:
        return self.frames[-1] if self.frames else None

    def show(self, frame: NDArray[np.uint8]) -> None:
        self.frames = [*self.frames, frame][-self.keep:]

    def close(self) -> None:
        self.frames = []


WINDOW_START_TIMEOUT_S = 30.0
WINDOW_REPLY_TIMEOUT_S = 10.0


class BeamerWindow:
    """A real borderless fullscreen window on display `screen` (pyglet), showing frames pixel for pixel.

    The window lives in its own process: pyglet's GLX context and the renderers' headless EGL contexts
    cannot both be current in one thread (libglvnd), and a window that hangs must not take the session down.
    The window must be exactly the projector's resolution: a scaled frame would be registered wrongly, so a
    mismatch is refused (pass allow_size_mismatch=True only for previews).
    """

    def __init__(self, width: int, height: int, screen: int = 0, allow_size_mismatch: bool = False) -> None:
        if not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY"):
            raise InputError("no display to show the beamer window on ($DISPLAY is not set)",
                             "connect the beamer as a display and set DISPLAY, or record with --output DIR")
        import multiprocessing

        context = multiprocessing.get_context("spawn")
        self._conn, child = context.Pipe()
        self._proc = context.Process(target=_window_process, name="arproj-beamer",
                                     args=(child, width, height, screen, allow_size_mismatch), daemon=True)
        self._proc.start()
        child.close()
        reply = self._receive(WINDOW_START_TIMEOUT_S, "open")
        if reply[0] == "error":
            self._stop()
            raise InputError(reply[1], reply[2])
        self.width, self.height, self.screen = width, height, screen
        self._fullscreen = bool(reply[1])
        self.closed_by_user = False

    def _receive(self, timeout_s: float, what: str) -> tuple:
        if not self._conn.poll(timeout_s):
            self._stop()
            raise InputError(f"the beamer window did not {what} within {timeout_s:.0f} s",
                             "check the display, or record with --output DIR")
        try:
            return self._conn.recv()
        except EOFError:
            self._stop()
            raise InputError("the beamer window closed unexpectedly", "check the display, or use --output DIR"
                             ) from None

    def show(self, frame: NDArray[np.uint8]) -> None:
        if self.closed_by_user:
            return
        self._conn.send(("show", as_rgb(frame)))
        reply = self._receive(WINDOW_REPLY_TIMEOUT_S, "show a frame")
        self.closed_by_user = reply[0] == "closed"

    def read_back(self) -> NDArray[np.uint8]:
        """What the window shows now, RGB (h, w, 3) top row first (for tests and self-checks)."""
        self._conn.send(("read",))
        return self._receive(WINDOW_REPLY_TIMEOUT_S, "read back")[1]

    @property
    def is_fullscreen(self) -> bool:
        return self._fullscreen

    def _stop(self) -> None:
        self._proc.join(timeout=2.0)
        if self._proc.is_alive():
            self._proc.terminate()
            self._proc.join(timeout=2.0)

    def close(self) -> None:
        if self._proc.is_alive():
            with contextlib.suppress(OSError, BrokenPipeError):
                self._conn.send(("close",))
        self._stop()
        self._conn.close()


def _window_process(conn: object, width: int, height: int, screen: int, allow_size_mismatch: bool) -> None:
    """The window's process: opens it (or reports why not), then shows frames until told to close."""
    try:
        import pyglet

        pyglet.options["shadow_window"] = False
        screens = pyglet.display.get_display().get_screens()
    except Exception as err:  # pyglet raises its own exception types per platform
        conn.send(("error", f"cannot open display {os.environ.get('DISPLAY')!r}: {err}",  # type: ignore
                   "check that the X server runs and DISPLAY points at it, or use --output DIR"))
        return
    if not 0 <= screen < len(screens):
        conn.send(("error", f"display has {len(screens)} screen(s); screen {screen} does not exist",  # type: ignore
                   f"pick --screen 0…{len(screens) - 1}"))
        return
    target = screens[screen]
    if (target.width, target.height) != (width, height) and not allow_size_mismatch:
        conn.send(("error", f"screen {screen} is {target.width}x{target.height} but the projector renders "  # type: ignore
                   f"{width}x{height}", "set the beamer to its native resolution, or pick its screen"))
        return
    try:
        window = pyglet.window.Window(width=target.width, height=target.height, fullscreen=True, screen=target,
                                      style=pyglet.window.Window.WINDOW_STYLE_BORDERLESS,
                                      caption="arproj beamer", vsync=False)
    except Exception as err:
        conn.send(("error", f"cannot open a fullscreen window on screen {screen}: {err}",  # type: ignore
                   "check the display, or record with --output DIR"))
        return
    window.set_mouse_visible(False)
    closed = {"by_user": False}

    @window.event
    def on_close() -> bool:  # the session stays up; the window only stops showing
        closed["by_user"] = True
        return True

    conn.send(("ok", window.fullscreen))  # type: ignore[attr-defined]
    while True:
        try:
            message = conn.recv()  # type: ignore[attr-defined]
        except EOFError:
            break
        if message[0] == "close":
            break
        window.switch_to()
        window.dispatch_events()
        if message[0] == "show":
            frame = message[1]
            h, w = frame.shape[:2]
            image = pyglet.image.ImageData(w, h, "RGB", frame.tobytes(), pitch=-w * 3)
            window.clear()
            image.blit(0, window.height - h)  # top-left anchored: projector pixel (0, 0) is the top-left
            window.flip()
            conn.send(("closed",) if closed["by_user"] else ("shown",))  # type: ignore[attr-defined]
        elif message[0] == "read":
            buffer = pyglet.image.get_buffer_manager().get_color_buffer().get_image_data()
            data = np.frombuffer(buffer.get_data("RGB", buffer.width * 3), dtype=np.uint8)
            conn.send(("image", data.reshape(buffer.height, buffer.width, 3)[::-1].copy()))  # type: ignore
    window.close()


SCREEN_REPLY_TIMEOUT_S = 10.0


class ScreenStream:
    """A screen at tcp://HOST:PORT that shows the frames sent to it (the simulated site's virtual screen, or a
    small display server beside a real beamer): each frame goes as a 4-byte big-endian length and a PNG, and
    show() returns once the screen answered with the line "ok" (an "error: …" line is an InputError naming it)."""

    def __init__(self, url: str, timeout_s: float = SCREEN_REPLY_TIMEOUT_S) -> None:
        self.url = url
        host, _, port = url.removeprefix("tcp://").rpartition(":")
        if not url.startswith("tcp://") or not host or not port.isdigit():
            raise InputError(f"screen {url!r} is not tcp://HOST:PORT", "e.g. --screen tcp://127.0.0.1:5000")
        try:
            self._sock = socket.create_connection((host, int(port)), timeout=timeout_s)
        except OSError as err:
            raise InputError(f"screen {url}: cannot connect ({err.strerror or err})",
                             "start the screen server (e.g. `python -m arproj.sim.live`) or check the URL") from None
        self._reader = self._sock.makefile("rb")

    def show(self, frame: NDArray[np.uint8]) -> None:
        frame = as_rgb(frame)
        ok, png = cv2.imencode(".png", cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
        if not ok:
            raise ValueError("could not encode the frame as PNG")
        try:
            self._sock.sendall(struct.pack(">I", len(png)) + png.tobytes())
            reply = self._reader.readline()
        except OSError as err:
            raise InputError(f"screen {self.url}: {err.strerror or err}", "check that the screen server runs"
                             ) from None
        if reply != b"ok\n":
            raise InputError(f"screen {self.url}: {reply.decode(errors='replace').strip() or 'no answer'}",
                             "check the projector size the screen expects")

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self._reader.close()
            self._sock.close()


def open_screen(screen: str, width: int, height: int) -> FrameOutput:
    """--screen N (a display: the beamer window, exactly width x height) or tcp://HOST:PORT (a ScreenStream)."""
    if screen.isdigit():
        return BeamerWindow(width, height, screen=int(screen))
    return ScreenStream(screen)

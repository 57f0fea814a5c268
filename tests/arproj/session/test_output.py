"""Beamer outputs: PNG sequence, and a real borderless fullscreen window under Xvfb."""

import os
import shutil
import subprocess

import cv2
import numpy as np
import pytest

from arproj.session.output import BeamerWindow, FileOutput
from geometry.errors import InputError


def _frame(w=320, h=200):
    frame = np.zeros((h, w, 3), np.uint8)
    frame[10:20, 30:50] = (255, 0, 0)
    frame[h - 5:, :4] = (0, 255, 0)
    return frame


def test_file_output_writes_the_exact_frames(tmp_path):
    out = FileOutput(tmp_path / "frames")
    frames = [_frame(), _frame()[::-1].copy()]
    for f in frames:
        out.show(f)
    assert [p.name for p in out.paths] == ["frame_00000.png", "frame_00001.png"]
    for path, f in zip(out.paths, frames, strict=True):
        assert np.array_equal(cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB), f)


def test_no_display_is_a_message(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(InputError, match="no display"):
        BeamerWindow(320, 200)


@pytest.fixture
def xvfb_display():
    if shutil.which("Xvfb") is None:
        pytest.skip("Xvfb is not on PATH (apt-get install xvfb): the fullscreen window test needs an X server")
    read_fd, write_fd = os.pipe()  # Xvfb picks a free display number and writes it here
    proc = subprocess.Popen(["Xvfb", "-displayfd", str(write_fd), "-screen", "0", "320x200x24", "-nolisten",
                             "tcp"], pass_fds=(write_fd,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    os.close(write_fd)
    with os.fdopen(read_fd) as pipe:
        number = pipe.readline().strip()
    if not number:
        proc.kill()
        pytest.skip("Xvfb did not start")
    display = f":{number}"
    old = os.environ.get("DISPLAY")
    os.environ["DISPLAY"] = display
    yield display
    if old is None:
        os.environ.pop("DISPLAY", None)
    else:
        os.environ["DISPLAY"] = old
    proc.terminate()
    proc.wait(timeout=10)


def test_fullscreen_window_shows_frames_pixel_for_pixel(xvfb_display):
    window = BeamerWindow(320, 200, screen=0)
    try:
        assert window.is_fullscreen
        frame = _frame()
        window.show(frame)
        window.show(frame)
        assert np.array_equal(window.read_back(), frame)
        with pytest.raises(InputError, match="screen 3 does not exist"):
            BeamerWindow(320, 200, screen=3)
    finally:
        window.close()
    with pytest.raises(InputError, match="is 320x200 but the projector renders 1280x800"):
        BeamerWindow(1280, 800, screen=0)

"""The simulated site served as live devices: frames shown on its screen reach its cameras, a stalled reader gets
no stale frame from LiveCamera, and bad frames are refused with the reason."""

from __future__ import annotations

import time

import numpy as np
import pytest

from arproj.session.output import ScreenStream
from arproj.sim.live import serve_live_site
from calibration.capture import LiveCamera, frames_agree, open_source
from geometry.errors import InputError


@pytest.mark.gl
def test_screen_frames_reach_the_cameras_and_stale_frames_are_skipped() -> None:
    with serve_live_site(seed=0, small=True) as live:
        w, h = live.projector_size
        screen = ScreenStream(live.urls.screen)
        camera = LiveCamera(open_source(live.urls.camera_left, "camera_left"), "camera_left")
        try:
            screen.show(np.zeros((h, w), np.uint8))
            dark = camera.settled_frame(time.monotonic() + 0.15)
            time.sleep(1.0)  # a reader that does nothing for a while (decoding, say) ...
            screen.show(np.full((h, w), 255, np.uint8))
            lit = camera.settled_frame(time.monotonic() + 0.15)  # ... still gets the new pattern, not old frames
            truth = live.photograph("camera_left")
            assert lit.mean() > dark.mean() + 20
            assert frames_agree(lit, truth[:, :] if truth.ndim == 2 else truth)
            with pytest.raises(InputError, match=f"the projector is {w}x{h}"):
                screen.show(np.zeros((h + 1, w), np.uint8))
        finally:
            camera.close()
            screen.close()


def test_screen_url_must_be_tcp() -> None:
    with pytest.raises(InputError, match="tcp://HOST:PORT"):
        ScreenStream("http://127.0.0.1:1")


def test_a_spawned_site_that_ignores_its_stdin_and_sigterm_is_killed_on_close(monkeypatch: pytest.MonkeyPatch
                                                                              ) -> None:
    # On a loaded machine a site once outlived both waits: close() raised TimeoutExpired and the finished
    # calibration it had served was lost with it. A stand-in process that ignores both signals is killed instead.
    import subprocess
    import sys

    import arproj.sim.live as live_module

    monkeypatch.setattr(live_module, "CLOSE_WAIT_S", 0.2)
    monkeypatch.setattr(live_module, "TERMINATE_WAIT_S", 0.2)
    stubborn = ("import signal, sys, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); print('up', flush=True); "
                "time.sleep(60)")
    site = live_module.SpawnedLiveSite.__new__(live_module.SpawnedLiveSite)
    site.process = subprocess.Popen([sys.executable, "-c", stubborn], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                    text=True)
    assert site.process.stdout is not None and site.process.stdout.readline() == "up\n"  # SIGTERM now ignored
    site.close()
    assert site.process.returncode is not None and site.process.returncode < 0

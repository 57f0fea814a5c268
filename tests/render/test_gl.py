"""render/gl.py: the one GL context factory (clear messages when no context can be had), releasing a bound
framebuffer without a GL error, and the error state the suite's GL fixture (tests/conftest.py) checks around
every GL test."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import moderngl
import pytest

from tests.support.gl import gl_error

GL_INVALID_ENUM_PROBE = 0xFFFF  # no GL capability has this enum


@pytest.mark.gl
def test_a_gl_error_shows_in_ctx_error_once(gl_context: moderngl.Context) -> None:
    """What the fixture relies on: an error a test leaves is seen by ctx.error, and reading it clears it."""
    assert gl_error(gl_context) == "GL_NO_ERROR"
    with gl_context:   # GL calls go to the current context: make this one current, as the renderer does
        gl_context.enable_direct(GL_INVALID_ENUM_PROBE)   # glEnable(0xFFFF): GL_INVALID_ENUM, passed on as is
    assert gl_error(gl_context) == "GL_INVALID_ENUM"
    assert gl_error(gl_context) == "GL_NO_ERROR"


@pytest.mark.gl
@pytest.mark.parametrize("release", ["plain", "release_framebuffer"])
def test_releasing_the_bound_framebuffer(gl_context: moderngl.Context, release: str) -> None:
    """moderngl binds the bound framebuffer again after making a new one: released plainly, the bound one's
    name is gone and that is GL_INVALID_OPERATION; release_framebuffer binds the default one first."""
    from render.gl import release_framebuffer

    with gl_context:
        texture = gl_context.texture((4, 4), 4)
        fbo = gl_context.framebuffer([texture])
        fbo.use()
        if release == "plain":
            fbo.release()
        else:
            release_framebuffer(fbo)
        other = gl_context.framebuffer([texture])
    assert gl_error(gl_context) == ("GL_INVALID_OPERATION" if release == "plain" else "GL_NO_ERROR")
    with gl_context:
        gl_context.detect_framebuffer(0).use()   # the plain case left the released one bound: not for later tests
        other.release()
        texture.release()


def test_missing_egl_is_a_one_line_message(monkeypatch: pytest.MonkeyPatch) -> None:
    import ctypes.util

    from render.gl import GLUnavailableError, create_context

    monkeypatch.setattr(ctypes.util, "find_library", lambda name: None)
    with pytest.raises(GLUnavailableError) as err:
        create_context()
    message = str(err.value)
    assert "libEGL.so not found" in message and "apt-get install" in message and "\n" not in message


def test_cli_reports_an_unavailable_gl_backend_without_a_traceback(tmp_path: Path) -> None:
    env = {"ARPROJ_GL_BACKEND": "vulkan", "PATH": "/usr/bin:/bin"}
    done = subprocess.run([sys.executable, "-c", "from arproj.cli import main; main()", "demo",
                           "--out", str(tmp_path / "demo")], capture_output=True, text=True, env=env,
                          timeout=120)
    assert done.returncode == 2
    assert "Traceback" not in done.stderr
    assert "ARPROJ_GL_BACKEND='vulkan'" in done.stderr

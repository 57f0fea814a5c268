"""The only place a GL context is created.

Headless EGL by default (Mesa's llvmpipe is enough: no GPU, no display). The backend can be chosen by
argument or by ARPROJ_GL_BACKEND (egl, or x11 for a context on $DISPLAY). When EGL cannot be had, the
error says in one line what is missing and how to get it.
"""

from __future__ import annotations

import ctypes.util
import os
from typing import Any

import moderngl

from geometry.errors import InputError

REQUIRED_GL_VERSION = 330


class GLUnavailableError(InputError):
    """No OpenGL 3.3 context could be created."""


def create_context(backend: str | None = None) -> moderngl.Context:
    """A standalone moderngl context (OpenGL ≥ 3.3 core). Release it with ctx.release()."""
    backend = (backend or os.environ.get("ARPROJ_GL_BACKEND") or "egl").lower()
    if backend not in ("egl", "x11"):
        raise GLUnavailableError(f"ARPROJ_GL_BACKEND={backend!r} is not a backend arproj knows",
                                 "use egl (headless) or x11")
    if backend == "egl":
        for lib in ("EGL", "GL"):
            if ctypes.util.find_library(lib) is None:
                raise GLUnavailableError(
                    f"cannot create a headless GL context: lib{lib}.so not found",
                    "install Mesa's EGL and GL drivers (Debian: apt-get install libegl1 libgl1 "
                    "libgl1-mesa-dri)")
    try:
        kwargs: dict[str, Any] = {"backend": "egl"} if backend == "egl" else {}
        ctx = moderngl.create_context(standalone=True, require=REQUIRED_GL_VERSION, **kwargs)
    except Exception as err:  # glcontext raises bare Exceptions with driver text
        first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        hint = ("install Mesa's EGL and GL drivers (Debian: apt-get install libegl1 libgl1-mesa-dri)"
                if backend == "egl" else "start an X server (e.g. Xvfb) and set DISPLAY, or use egl")
        raise GLUnavailableError(f"cannot create a {backend.upper()} GL {REQUIRED_GL_VERSION // 100}."
                                 f"{REQUIRED_GL_VERSION // 10 % 10} context: {first}", hint) from None
    return ctx


def release_framebuffer(fbo: moderngl.Framebuffer) -> None:
    """fbo.release(), first binding the default framebuffer if fbo is the bound one (call it with the context
    current). moderngl binds the bound framebuffer again after making another; once released, its name is
    gone and that bind is GL_INVALID_OPERATION."""
    ctx = fbo.ctx
    if ctx.fbo is fbo:
        ctx.detect_framebuffer(0).use()
    fbo.release()

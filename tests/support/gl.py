"""Reading a GL context's error state in the tests."""

from __future__ import annotations

import moderngl


def gl_error(ctx: moderngl.Context) -> str:
    """ctx.error, read with ctx current: glGetError answers for the current context, and after earlier tests
    another context (a site's shared one, a command's own) may be current, or none."""
    with ctx:
        return ctx.error

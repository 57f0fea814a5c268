"""GLSL sources, loaded by name through one cached loader.

A file `NAME.glsl` holds one program: `#if defined VERTEX_SHADER … #elif defined FRAGMENT_SHADER … #endif`
(pyrender/moderngl-window style). `program_source(name, defines)` returns the vertex and fragment sources
with `#version` first and the stage and any extra `#define`s injected after it.
"""

from __future__ import annotations

from functools import cache
from importlib import resources
from typing import TypedDict

GLSL_VERSION = "#version 330 core"


@cache
def source(name: str) -> str:
    """The text of shaders/NAME.glsl (cached; raises FileNotFoundError naming the shader)."""
    try:
        return resources.files(__name__).joinpath(f"{name}.glsl").read_text()
    except FileNotFoundError:
        raise FileNotFoundError(f"shader {name!r} not found: expected shaders/{name}.glsl") from None


class ProgramSource(TypedDict):
    """The keyword arguments of moderngl's ctx.program for one program's two stages."""

    vertex_shader: str
    fragment_shader: str


def program_source(name: str, defines: dict[str, object] | None = None) -> ProgramSource:
    """{'vertex_shader': …, 'fragment_shader': …} for moderngl's ctx.program(**…)."""
    body = source(name)
    extra = "".join(f"#define {k} {v}\n" for k, v in (defines or {}).items())
    return {
        "vertex_shader": f"{GLSL_VERSION}\n#define VERTEX_SHADER\n{extra}#line 1\n{body}",
        "fragment_shader": f"{GLSL_VERSION}\n#define FRAGMENT_SHADER\n{extra}#line 1\n{body}",
    }

"""Fixtures shared by the whole suite."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.support.gl import gl_error

REPO = Path(__file__).resolve().parent.parent


def shared_data_dir() -> Path:
    """../shared/data beside the repository, or where ARPROJ_DATA points."""
    return Path(os.environ.get("ARPROJ_DATA", REPO.parent / "shared" / "data"))


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The real-image folder; tests that need it skip with the reason when it is absent."""
    path = shared_data_dir()
    if not path.is_dir():
        pytest.skip(f"real calibration images not found at {path} (set ARPROJ_DATA or place ../shared beside "
                    "the repository)")
    return path


@pytest.fixture(scope="session")
def gl_context() -> Iterator[object]:
    """One EGL context for the whole session (llvmpipe is enough), made by the one factory, released at the end."""
    from render.gl import create_context

    ctx = create_context()
    yield ctx
    ctx.release()


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """A test that uses the GL context renders: it carries the `gl` marker whether or not it says so."""
    for item in items:
        if "gl_context" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.gl)


@pytest.fixture(autouse=True)
def _gl_error_free(request: pytest.FixtureRequest) -> Iterator[None]:
    """Around every GL test (marker `gl`): no GL error on the session's context before it (a clean start) or
    after it, as moderngl's own suite checks. Contexts a command makes for itself (the demo, `arproj project
    --sim`, sites built without ctx) are not seen here."""
    if request.node.get_closest_marker("gl") is None:
        yield
        return
    ctx = request.getfixturevalue("gl_context")
    assert gl_error(ctx) == "GL_NO_ERROR", "a GL error was left by an earlier test"
    yield
    assert gl_error(ctx) == "GL_NO_ERROR", f"{request.node.name} left a GL error"

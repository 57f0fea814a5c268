"""Offscreen rendering: OpenCV intrinsics and poses drawn with moderngl through one GL context factory."""

from render.renderer import MeshRenderer, RenderResult

__all__ = ["MeshRenderer", "RenderResult"]

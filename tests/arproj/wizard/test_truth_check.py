"""The live calibration's truth checks: each camera's intrinsics against the site's truth and its 95 % bound."""

from __future__ import annotations

from dataclasses import replace

from arproj.wizard.live_steps import truth_check
from geometry.intrinsics import Intrinsics
from geometry.rig import Rig


def _doc(intr: Intrinsics) -> dict:
    return {"fx": intr.fx, "fy": intr.fy, "cx": intr.cx, "cy": intr.cy, "width": intr.width,
            "height": intr.height, "dist": list(intr.dist)}


def test_camera_intrinsics_are_judged_against_their_bounds() -> None:
    true = Intrinsics(457.0, 457.0, 319.5, 199.5, 640, 400, (-0.12, 0.06, 0.0, 0.0, 0.0))
    rig = Rig(intrinsics={"camera_left": replace(true, cx=true.cx + 0.3, fy=true.fy - 2.0),
                          "camera_right": replace(true, cy=true.cy - 0.1)})
    bounds = {"camera_left": {"fx": 1.0, "fy": 1.0, "cx": 0.5, "cy": 0.5},
              "camera_right": {"fx": 1.0, "fy": 1.0, "cx": 0.5, "cy": 0.05}}
    out = truth_check({"camera_left": _doc(true), "camera_right": _doc(true)}, rig=rig, cameras_95=bounds)
    assert set(out) == {f"camera {side} {k}" for side in ("left", "right") for k in ("fx", "fy", "cx", "cy")}
    assert abs(out["camera left cx"]["error"] - 0.3) < 1e-9 and out["camera left cx"]["within"]
    assert abs(out["camera left cx"]["share_of_bound"] - 0.6) < 1e-9
    assert not out["camera left fy"]["within"] and out["camera left fy"]["share_of_bound"] == 2.0
    assert not out["camera right cy"]["within"] and out["camera right fx"]["within"]
    # without the stereo step's bounds (cameras from the rig file) nothing is judged for them
    assert truth_check({"camera_left": _doc(true)}, rig=rig) == {}

"""Scene configuration of the simulated site: defaults, loading, merging and validation.

The defaults live in arproj/sim/scenes/default.yaml (documented there key by key). A user's scene file or
dict holds only the keys it changes; unknown keys, wrong types and impossible values raise InputError
naming the key and the value. Geometric checks (camera inside a wall, projector facing away) happen when
the site is built, where the geometry is known (arproj.sim.site).
"""

from __future__ import annotations

import copy
from functools import cache
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from geometry.errors import InputError
from geometry.inputs import fail, integer, is_number, load_document, number

Scene = dict[str, Any]

# Keys whose default is null: any number (or null) is accepted.
_NULLABLE = {"robot.along_m", "robot.head_deg", "projector.focus_distance_m"}
# Keys that are free-form mappings, checked by their own rules.
_FREE_MAPPINGS = {"room.walls", "cameras.right"}
_WALL_OVERRIDE_KEYS = {"albedo", "texture", "texture_contrast"}
TEXTURES = ("plaster", "wallpaper", "flat")

# Value rules: key → (check, what the value must be).
_POSITIVE = "must be > 0"
_NON_NEGATIVE = "must be ≥ 0"
_FRACTION = "must be between 0 and 1"
_RULES: dict[str, str] = {
    "room.height_m": _POSITIVE, "room.ambient_lux": _NON_NEGATIVE, "room.wall_albedo": _FRACTION,
    "room.texture_contrast": _FRACTION, "room.texel_m": _POSITIVE, "room.floor_albedo": _FRACTION,
    "room.ceiling_albedo": _FRACTION,
    "robot.distance_m": _POSITIVE, "robot.aim_height_m": _NON_NEGATIVE, "robot.footprint_radius_m": _POSITIVE,
    "robot.localization_sigma_m": _NON_NEGATIVE, "robot.localization_sigma_deg": _NON_NEGATIVE,
    "robot.floor_tilt_sigma_deg": _NON_NEGATIVE,
    "robot.along_m": _NON_NEGATIVE,
    "head.axis_error_deg": _NON_NEGATIVE, "head.point_error_m": _NON_NEGATIVE,
    "head.angle_noise_deg": _NON_NEGATIVE, "head.backlash_deg": _NON_NEGATIVE,
    "projector.width": _POSITIVE, "projector.height": _POSITIVE, "projector.throw_ratio": _POSITIVE,
    "projector.lumens": _NON_NEGATIVE, "projector.contrast_ratio": _POSITIVE, "projector.gamma": _POSITIVE,
    "projector.aperture_mm": _NON_NEGATIVE, "projector.focus_distance_m": _POSITIVE,
    "projector.lens_blur_px": _NON_NEGATIVE, "projector.uniformity": _FRACTION,
    "cameras.width": _POSITIVE, "cameras.height": _POSITIVE, "cameras.hfov_deg": _POSITIVE,
    "cameras.baseline_m": _POSITIVE, "cameras.exposure_s": _POSITIVE, "cameras.responsivity": _POSITIVE,
    "cameras.full_well_e": _POSITIVE, "cameras.read_noise_e": _NON_NEGATIVE, "cameras.gamma": _POSITIVE,
    "cameras.aperture_mm": _NON_NEGATIVE, "cameras.focus_distance_m": _POSITIVE,
    "cameras.lens_blur_px": _NON_NEGATIVE, "cameras.prnu": _FRACTION,
    "cameras.mount_error_deg": _NON_NEGATIVE, "cameras.mount_error_m": _NON_NEGATIVE,
    "laser.fov_deg": _POSITIVE, "laser.resolution_deg": _POSITIVE, "laser.range_max_m": _POSITIVE,
    "laser.range_sigma_m": _NON_NEGATIVE, "laser.outlier_fraction": _FRACTION,
    "rangecam.width": _POSITIVE, "rangecam.height": _POSITIVE, "rangecam.hfov_deg": _POSITIVE,
    "rangecam.range_min_m": _POSITIVE, "rangecam.range_max_m": _POSITIVE,
    "rangecam.sigma_at_1m_m": _NON_NEGATIVE, "rangecam.step_at_1m_m": _NON_NEGATIVE,
    "rangecam.edge_dropout_px": _NON_NEGATIVE,
    "rangecam.grazing_limit_deg": _POSITIVE, "rangecam.dropout_fraction": _FRACTION,
}
_BELOW_180 = {"cameras.hfov_deg", "rangecam.hfov_deg", "rangecam.grazing_limit_deg"}
# Physical ranges beyond the rules above: image sizes the renderer can hold (a 100,000² beamer is 28 GiB),
# texture and beam steps that stay countable, a room and a robot of this world.
_LIMITS: dict[str, tuple[float, float]] = {
    "projector.width": (16, 4096), "projector.height": (16, 4096), "cameras.width": (16, 8192),
    "cameras.height": (16, 8192), "rangecam.width": (16, 2048), "rangecam.height": (16, 2048),
    "room.height_m": (0.5, 20.0), "room.texel_m": (0.001, 0.1), "laser.resolution_deg": (0.01, 10.0),
    "laser.fov_deg": (1.0, 360.0), "laser.range_max_m": (0.1, 100.0), "robot.distance_m": (0.1, 50.0),
    "robot.aim_height_m": (0.0, 20.0), "robot.along_m": (0.0, 100.0), "robot.footprint_radius_m": (0.01, 5.0),
    "robot.floor_tilt_sigma_deg": (0.0, 5.0),
    "rangecam.range_max_m": (0.01, 100.0), "cameras.baseline_m": (0.001, 10.0),
    "cameras.exposure_s": (1e-6, 10.0), "projector.throw_ratio": (0.05, 20.0),
}
MAX_ABS = 1e6  # any number of a scene; the ranges above are tighter where a value sizes memory or time
MAX_ROOM_M = 50.0  # room corners, metres from the origin


@cache
def _default_text() -> str:
    return resources.files("arproj.sim").joinpath("scenes/default.yaml").read_text()


def default_scene() -> Scene:
    """The default scene as a fresh nested dict."""
    return yaml.safe_load(_default_text())


def load_scene(scene: str | Path | dict | None = None, **overrides: Any) -> Scene:
    """The full, validated scene: defaults updated by a scene file or dict, then by keyword overrides.

    overrides are sections (`robot={"distance_m": 3.0}`) merged key by key like a scene file.
    Raises InputError naming the source, key and value for anything unknown, mistyped or impossible.
    """
    result = default_scene()
    source = "scene"
    if isinstance(scene, (str, Path)):
        source = str(scene)
        user = _read_yaml(Path(scene))
        _merge(result, user, source, "")
    elif isinstance(scene, dict):
        _merge(result, copy.deepcopy(scene), source, "")
    elif scene is not None:
        raise InputError(f"scene must be a YAML file path or a dict, got {type(scene).__name__}")
    if overrides:
        _merge(result, copy.deepcopy(overrides), "overrides", "")
    _validate(result, source)
    return result


def _read_yaml(path: Path) -> dict:
    doc = load_document(path, "scene file", "pass a YAML scene (see arproj/sim/scenes/default.yaml)")
    if doc is None:
        return {}
    if not isinstance(doc, dict):
        raise InputError(f"{path}: a scene file must be a mapping of sections (room, robot, …), "
                         f"got {type(doc).__name__}")
    return doc


def _merge(base: dict, user: dict, source: str, prefix: str) -> None:
    for key, value in user.items():
        dotted = f"{prefix}{key}"
        if key not in base:
            known = ", ".join(str(k) for k in base)
            raise InputError(f"{source}: unknown key {dotted!r} (value {value!r})", f"known keys here: {known}")
        if dotted in _FREE_MAPPINGS:
            if not isinstance(value, dict):
                raise InputError(f"{source}: {dotted} must be a mapping, got {value!r}")
            base[key] = value
        elif isinstance(base[key], dict):
            if not isinstance(value, dict):
                raise InputError(f"{source}: {dotted} must be a mapping of keys, got {value!r}")
            _merge(base[key], value, source, dotted + ".")
        else:
            base[key] = _typed(base[key], value, dotted, source)


def _typed(default: Any, value: Any, key: str, source: str) -> Any:
    """value converted to the default's type, or InputError."""
    if value is None:
        if key in _NULLABLE:
            return None
        raise InputError(f"{source}: {key} may not be null", f"the default is {default!r}")
    if key == "robot.head_deg":
        return _number_list(value, key, source, 3)
    if (default is None and key in _NULLABLE) or isinstance(default, float):
        return number(source, key, value, -MAX_ABS, MAX_ABS)
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise InputError(f"{source}: {key} must be true or false, got {value!r}")
        return value
    if isinstance(default, int):
        return integer(source, key, value, -int(MAX_ABS), int(MAX_ABS))
    if isinstance(default, str):
        if not isinstance(value, str):
            raise InputError(f"{source}: {key} must be a string, got {value!r}")
        return value
    if isinstance(default, list):
        if not isinstance(value, list):
            raise InputError(f"{source}: {key} must be a list, got {value!r}")
        return value
    raise InputError(f"{source}: {key} has an unexpected value {value!r}")


def _number_list(value: Any, key: str, source: str, length: int | None = None) -> list:
    flat = value if isinstance(value, list) else [value]
    if not all(is_number(v) for v in flat) or (length is not None and len(flat) != length) or len(flat) > 64:
        shape = f"{length} numbers" if length is not None else "numbers"
        raise fail(source, key, value, f"must be a list of {shape}")
    return [number(source, f"{key}[{i}]", v, -MAX_ABS, MAX_ABS) for i, v in enumerate(flat)]


def _check_rule(rule_key: str, key: str, value: Any, source: str) -> None:
    """InputError naming key and value when value breaks the rule registered for rule_key."""
    if value is None:
        return
    rule = _RULES[rule_key]
    bad = ((rule == _POSITIVE and not value > 0) or (rule == _NON_NEGATIVE and not value >= 0)
           or (rule == _FRACTION and not 0 <= value <= 1))
    if bad or (rule_key in _BELOW_180 and value >= 180):
        raise InputError(f"{source}: {key} = {value!r} {rule if bad else 'must be below 180'}")


def _validate(scene: Scene, source: str) -> None:
    for key in _RULES:
        section, name = key.split(".")
        _check_rule(key, key, scene[section][name], source)
    for key, (lo, hi) in _LIMITS.items():
        section, name = key.split(".")
        if scene[section][name] is not None:
            number(source, key, scene[section][name], lo, hi)

    room = scene["room"]
    corners = room["corners_m"]
    if len(corners) < 3:
        raise InputError(f"{source}: room.corners_m needs at least 3 corners, got {corners!r}")
    if len(corners) > 64:
        raise fail(source, "room.corners_m", corners, "a room has at most 64 corners")
    room["corners_m"] = [_number_list(c, f"room.corners_m[{i}]", source, 2) for i, c in enumerate(corners)]
    far = [c for c in room["corners_m"] if max(abs(c[0]), abs(c[1])) > MAX_ROOM_M]
    if far:
        raise fail(source, "room.corners_m", far[0], f"a corner more than {MAX_ROOM_M:g} m from the origin")
    if room["wall_texture"] not in TEXTURES:
        raise InputError(f"{source}: room.wall_texture = {room['wall_texture']!r} is not one of {TEXTURES}")
    walls = {}
    for index, override in room["walls"].items():
        try:
            i = int(index)
        except (TypeError, ValueError, OverflowError):
            raise InputError(f"{source}: room.walls key {index!r} must be a wall index (0..)") from None
        if not 0 <= i < len(corners):
            raise InputError(f"{source}: room.walls has wall {i}, but the room has {len(corners)} walls "
                             f"(0..{len(corners) - 1})")
        if not isinstance(override, dict) or set(override) - _WALL_OVERRIDE_KEYS:
            raise InputError(f"{source}: room.walls.{i} = {override!r}: allowed keys are "
                             f"{sorted(_WALL_OVERRIDE_KEYS)}")
        if "texture" in override and override["texture"] not in TEXTURES:
            raise InputError(f"{source}: room.walls.{i}.texture = {override['texture']!r} is not one of "
                             f"{TEXTURES}")
        for k in ("albedo", "texture_contrast"):
            if k in override:
                v = _number_list(override[k], f"room.walls.{i}.{k}", source, 1)[0]
                if not 0 <= v <= 1:
                    raise InputError(f"{source}: room.walls.{i}.{k} = {v!r} must be between 0 and 1")
                override[k] = v
        walls[i] = override
    room["walls"] = walls

    if not 0 <= scene["robot"]["wall"] < len(corners):
        raise InputError(f"{source}: robot.wall = {scene['robot']['wall']!r}, but the room has walls "
                         f"0..{len(corners) - 1}")
    if abs(scene["robot"]["incidence_deg"]) >= 85:
        raise InputError(f"{source}: robot.incidence_deg = {scene['robot']['incidence_deg']!r} is too oblique",
                         "use an angle between -85 and 85 degrees")

    head = scene["head"]
    for k in ("pan_point_m", "tilt_point_m", "projector_position_m", "angle_bias_deg"):
        head[k] = _number_list(head[k], f"head.{k}", source, 3)
    limits = head["limits_deg"]
    if not isinstance(limits, list) or len(limits) != 3:
        raise InputError(f"{source}: head.limits_deg must be three [min, max] pairs, got {limits!r}")
    head["limits_deg"] = [_number_list(p, f"head.limits_deg[{i}]", source, 2) for i, p in enumerate(limits)]
    for i, (lo, hi) in enumerate(head["limits_deg"]):
        if not lo < 0 < hi:
            raise InputError(f"{source}: head.limits_deg[{i}] = {[lo, hi]!r} must contain 0 (min < 0 < max)")

    for section in ("projector", "cameras"):
        dist = _number_list(scene[section]["dist"], f"{section}.dist", source)
        if len(dist) not in (4, 5, 8):
            raise InputError(f"{source}: {section}.dist has {len(dist)} coefficients; the simulator takes "
                             "4, 5 or 8 (OpenCV k1 k2 p1 p2 [k3 [k4 k5 k6]])")
        scene[section]["dist"] = dist
    cams = scene["cameras"]
    for k in ("position_m",):
        cams[k] = _number_list(cams[k], f"cameras.{k}", source, 3)
    right = {}
    for k, v in cams["right"].items():
        key = f"cameras.right.{k}"
        pair_keys = {"right", "baseline_m", "position_m", "pitch_deg", "toe_in_deg", "color", "msaa_samples",
                     "mount_error_deg", "mount_error_m"}
        if k in pair_keys or k not in cams:
            allowed = sorted(set(cams) - pair_keys)
            raise InputError(f"{source}: unknown key {key!r} (value {v!r})", f"the right camera may override "
                             f"{', '.join(allowed)}")
        right[k] = _typed(cams[k], v, key, source)
        if k == "dist":
            right[k] = _number_list(v, key, source)
            if len(right[k]) not in (4, 5, 8):
                raise InputError(f"{source}: {key} has {len(right[k])} coefficients; use 4, 5 or 8")
        elif f"cameras.{k}" in _RULES:
            _check_rule(f"cameras.{k}", key, right[k], source)
        if f"cameras.{k}" in _LIMITS:
            number(source, key, right[k], *_LIMITS[f"cameras.{k}"])
    cams["right"] = right
    if cams["msaa_samples"] not in (0, 2, 4, 8):
        raise InputError(f"{source}: cameras.msaa_samples = {cams['msaa_samples']!r} must be 0, 2, 4 or 8")
    laser = scene["laser"]
    laser["position_m"] = _number_list(laser["position_m"], "laser.position_m", source, 3)
    rc = scene["rangecam"]
    if rc["range_min_m"] >= rc["range_max_m"]:
        raise InputError(f"{source}: rangecam.range_min_m = {rc['range_min_m']} must be below range_max_m = "
                         f"{rc['range_max_m']}")

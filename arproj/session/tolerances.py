"""Numeric tolerances and defaults of the projection session, in one place (metres unless named _mm/_deg)."""

from __future__ import annotations

from mapping.drill import BASE_SAFETY_MARGIN_M, Z95  # noqa: F401  (one source: the drill check's numbers)
from mapping.mapfile import DEFAULT_SIGMA_M as DEFAULT_MAP_SIGMA_M  # noqa: F401

# Safety gate: a map is shown only while the registration error on the wall is believed (95 %) below this.
REGISTRATION_TOLERANCE_M = 0.010
# Safety band: drawn half-width = object half-width + BASE_MARGIN + Z95 · sqrt(σ_map² + σ_registration²); the
# drill check (mapping.drill) judges by the same numbers.
# (BASE_SAFETY_MARGIN_M, Z95 and DEFAULT_MAP_SIGMA_M come from mapping, imported above)

TRUTH_COVERAGE_CELL_M = 0.004  # coverage grid of a map made from a wall file's truth (every cell looked at)

# Overlay raster on the wall (texture of the projected mesh)
OVERLAY_PX_PER_M = 500.0  # 2 mm per texel: below one projector pixel's footprint at 2 m
OVERLAY_MAX_TEXELS = 4096  # per side (GL texture limit that llvmpipe and every GPU supports)
MAP_LAYER_OPACITY = 0.45  # the mapping's own texture is drawn dimmer than the object bands

# DIN 18015-3 installation zones for electrical lines (metres, from the finished floor / ceiling / corner)
DIN_ZONE_WIDTH_M = 0.30
DIN_HORIZONTAL_TOP_FROM_CEILING_M = (0.15, 0.45)
DIN_HORIZONTAL_BOTTOM_FROM_FLOOR_M = (0.15, 0.45)
DIN_HORIZONTAL_MIDDLE_FROM_FLOOR_M = (0.90, 1.30)  # only on walls with work surfaces (kitchens)
DIN_VERTICAL_FROM_EDGE_M = (0.10, 0.30)  # beside wall corners, doors and windows
DIN_ZONE_OPACITY = 0.18
DIN_SOCKET_HALF_WIDTH_M = 0.10  # a known socket's lines run vertically to it: a strip this far either side
DIN_ZONE_WORDS = "zone: expect lines here"  # what a zone says where the wall was not scanned (never "safe")

# Closed loop
CLOSED_LOOP_MAX_CORRECTION_M = 0.006  # larger offsets are not "small": re-estimate instead of correcting
CLOSED_LOOP_MIN_FEATURES = 6
TRUTH_MAP_SIGMA_M = 0.0005  # a map taken from a wall file's truth is exact but for rounding

# Trusted region: the map is drawn only where the expected registration error (95 %) plus a reserve for the
# closed loop's worst check mark stays within the tolerance, and only when that covers at least MIN_TRUSTED_SHARE
# of the drawn area. The gate adds the loop's measured worst mark to the pose's 95 % error, so a fine map is
# warned when its worst mark exceeds the reserve: the reserve is fitted on the TUNING seeds of
# `arproj bench projection` (the worst mark's error on fine rendered scenes, its 99th percentile rounded up to
# 0.5 mm; the bench prints the fit beside this value and judges the gate on other seeds). It replaces a fixed
# 40 % of the tolerance (4 mm), which cut the map at 4 m to 69 % of its area though fine marks stay near 1 mm.
CLOSED_LOOP_RESERVE_M = 0.002
MIN_TRUSTED_SHARE = 0.2

"""Numeric tolerances and defaults of the mapping package, in one place (SI units: metres, radians)."""

from __future__ import annotations

# Grid
DEFAULT_RESOLUTION_M = 0.004  # map cell size; finer than the 1 cm raster so sub-cell peaks stay sharp
SIGNAL_SPLAT_SIGMA_M = 0.004  # Gaussian footprint with which a sample's reading is spread onto the grid
KNOWN_WEIGHT = 0.05  # footprint weight a cell needs to count as observed (≈ a sample within 2σ); else unknown

POSITION_SIGMA_M = 0.002  # 1σ position uncertainty of mapped objects (bench mapping: mean error ≈ 1 mm)

# Log-odds clamping (as in ROS/octomap: keeps a cell able to change its mind)
LOG_ODDS_MIN = -4.0
LOG_ODDS_MAX = 4.0

# Object extraction
RIDGE_MIN_POINTS = 12  # Steger points needed for a line segment
LINE_INLIER_M = 0.004  # distance of a ridge point to its segment's line
LINE_GAP_M = 0.04  # a longer gap between ridge points along a line splits it
LINE_MIN_LENGTH_M = 0.06  # shorter straight ridges are not pipes or cables
MIN_RUN_M = 0.04  # straight runs shorter than this inside a ridge chain are dropped (end hooks)
JOIN_ENDPOINT_M = 0.05  # segment ends this close are joined into one polyline
BRIDGE_GAP_M = 0.30  # longest gap bridged between collinear pieces where other lines cross the gap
BRIDGE_MAX_ANGLE_DEG = 4.0  # both pieces' end directions must agree with the gap this well
BRIDGE_CROSSING_M = 0.08  # ... and another line comes this close to the gap (it may be interrupted too)
JOIN_MIN_ANGLE_DEG = 12.0  # segments meeting at a smaller angle are merged into one straight run

# Plane fitting
PLANE_INLIER_M = 0.01  # RANSAC inlier distance for laser / range points on a wall
PLANE_MIN_POINTS = 10  # fewer sound points cannot give a trustworthy plane
RANSAC_ITERATIONS = 200

# Surface mesh
DEPTH_JUMP_RATIO = 0.05  # neighbours whose depths differ by more than this fraction are not joined


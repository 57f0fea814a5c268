"""Numeric tolerances and evidence thresholds of the wall-pose estimator, in one place.

Pixel figures are camera pixels at full resolution; angles in degrees; lengths in metres.
"""

# --- pattern layout ------------------------------------------------------------------------------------------
MIN_SQUARE_CAMERA_PX = 12.0     # smallest checker square as seen by a camera (after foreshortening)
MIN_MARKER_DETECT_PX = 28.0     # smallest marker side in the (downscaled) image the marker detector sees
PATTERN_MARGIN_FRACTION = 0.04  # free border around the pattern, fraction of the projector image
MARKER_SPACING_SQUARES = 6      # roughly one coded marker block every this many squares

# --- detection -------------------------------------------------------------------------------------------------
MARKER_DETECT_MAX_PX = 800      # the marker detector runs on an image downscaled to at most this width
MAX_CORNERS = 650               # more visible corners than this: an even subset is refined and fitted
SUBPIX_ITERATIONS = 30
SUBPIX_EPS_PX = 0.002
MAX_CORNER_SHIFT_PX = 2.5       # refined corner farther than this from its prediction: rejected
MAX_CORNER_SHIFT_REFINED_PX = 0.75  # the same once the homography comes from refined corners
MIN_NEIGHBOURHOOD_CONTRAST = 100.0  # flattened grey levels between the 16 squares' expected whites and blacks
MIN_NEIGHBOURHOOD_AGREEMENT = 0.9   # fraction of those squares on the expected side of mid-grey
MIN_CORNER_CONTRAST = 12.0      # grey levels between the white and black quadrants around a corner
CLIPPED_LEVEL = 250             # grey level counted as clipped (over-exposed)
MAX_CLIPPED_FRACTION = 0.30     # more of the pattern's white area clipped than this: over-exposed
MIN_PATTERN_CONTRAST = 15.0     # median white-black difference below this: low contrast

# --- plane fit -----------------------------------------------------------------------------------------------
MIN_CORNERS = 12                # fewer inlier corners than this: not enough evidence
MIN_INLIER_FRACTION = 0.30      # fewer inliers among all matched corners: the pattern is not on one plane
RANSAC_ITERATIONS = 96
RANSAC_SCORE_CORNERS = 200       # hypotheses are ranked on at most this many corners (an even subset)
RANSAC_THRESHOLD_PX = 0.6      # stereo transfer error; off-plane corners 1 cm from the plane at 2 m exceed it
INLIER_SIGMAS = 5.0             # final inliers: corner error within this many robust sigmas ...
INLIER_FLOOR_PX = 0.3           # ... or this many pixels, whichever is larger
SIGMA_FLOOR_PX = 0.02           # corner noise is never taken as smaller than this
MAX_RMS_PX = 0.6                # a-posteriori corner noise above this: the views do not agree
MAX_NOISE_RATIO = 1.5           # joint corner noise this many times that of each camera alone: views disagree
CHI2_3_999 = 16.27              # 99.9 % quantile of chi-square with 3 degrees of freedom
CHI2_2_95 = 5.991               # 95 % quantile, 2 degrees of freedom (the normal's direction)
Z_95 = 1.960                    # 95 % two-sided normal quantile (a distance)
MAX_NORMAL_95_DEG = 1.0         # a pose whose normal is less certain than this is not reported as known
MAX_DISTANCE_95_M = 0.02        # likewise for the distance at the pattern's centre
GAUSS_NEWTON_ITERATIONS = 8

# --- projector pose prior (head repeatability: commanded vs true joint angles) ---------------------------------
PROJECTOR_ROTATION_SIGMA_DEG = 0.2
PROJECTOR_TRANSLATION_SIGMA_M = 0.003
# --- what calibration and corner finding get wrong for a whole image alike ----------------------------------
IMAGE_OFFSET_SIGMA_PX = 0.015   # a common shift of all corners (e.g. a stereo rotation error)
IMAGE_GRADIENT_SIGMA_PX = 0.015 # a shift growing linearly to this at the image's edge (scale, shading)
# where the projector's light really lands vs its model (projector pixels): intrinsics and lens blur that
# varies across the image shift the pattern's corners on the wall; the cameras see them where they land
PROJECTOR_OFFSET_SIGMA_PX = 0.15
PROJECTOR_GRADIENT_SIGMA_PX = 0.25
MAX_NUISANCE_SIGMAS = 4.0      # a correction this far beyond its prior: the images contradict the rig model

# --- full pose -----------------------------------------------------------------------------------------------
FLOOR_HEIGHT_SIGMA_M = 0.002    # the robot stands on the floor: its height is known this well
FLOOR_TILT_SIGMA_DEG = 0.1      # and its roll and pitch
TILT_CHECK_PRIOR_DEG = 2.0      # an inclinometer's reading is checked against the pose with the tilts this free
TILT_CHI2_2_999 = 13.82         # 99.9 % quantile, 2 degrees of freedom: a reading this far off is not used
LASER_GATE_M = 0.08             # scan points farther than this from every wall are not used
LASER_RANGE_SIGMA_M = 0.01

# --- the wall's edges seen by the cameras (room corners, floor and ceiling lines; edges.py) -------------------
EDGE_SAMPLES_3D = 800           # points along a 3-D edge when predicting its image
EDGE_IMAGE_MARGIN_PX = 8.0      # a search profile must stay this far inside the image
EDGE_PROFILE_SPACING_PX = 4.0   # search profiles this far apart along the predicted line
EDGE_PROFILE_HALF_WIDTH_PX = 2  # each profile averages 2·this+1 parallel rows (sensor noise, texture)
EDGE_WINDOW_SIGMAS = 5.0        # search ± this many σ of the predicted line's position ...
EDGE_WINDOW_EXTRA_PX = 4.0      # ... plus this (blur, the step's own width)
EDGE_WINDOW_MAX_PX = 80.0       # a wider search than this would meet too much else: no search
EDGE_MIN_CONTRAST = 6.0         # grey levels between the two surfaces meeting at the edge
EDGE_CANDIDATES_PER_PROFILE = 3 # strongest steps kept per profile (the pattern's edges cross it too)
EDGE_RANSAC_ITERATIONS = 200
EDGE_RANSAC_THRESHOLD_PX = 1.0
EDGE_INLIER_SIGMAS = 3.0        # final inliers: within this many robust sigmas of the fitted line ...
EDGE_INLIER_FLOOR_PX = 0.3      # ... or this many pixels, whichever is larger
EDGE_MIN_POINTS = 20            # fewer edge points on one line than this: no observation
EDGE_MIN_INLIER_FRACTION = 0.25 # of the profiles searched (the pattern may light much of the rest)
EDGE_MIN_LENGTH_PX = 80.0       # the fitted stretch of the line must be at least this long
EDGE_MAX_SIGMA_PX = 0.8         # edge points scatter more than this: not a clean edge
EDGE_MAX_ANGLE_DEG = 3.0        # fitted line's direction this far from the predicted one: not that edge
EDGE_SIGMA_FLOOR_PX = 0.1       # edge point noise is never taken as smaller than this
EDGE_SYSTEMATIC_PX = 0.12       # a shift common to a whole line (light and texture near it, calibration)
EDGE_CHI2_2_999 = 13.82         # 99.9 % quantile, 2 degrees of freedom: an edge this far off is rejected
EDGE_CAMERA_GAMMA = 2.2         # the cameras' encoding (grey = 255·light^(1/γ)): steps are located in linear light
EDGE_END_CLEARANCE_PX = 4.0     # profiles keep this much more than their own reach from the edge's ends
EDGE_CONTRAST_RATIO = 1.25      # edge points whose step is this many times taller (or lower) than the line's
                                # median are left out (the pattern lights that stretch)
EDGE_LIT_MARGIN_FRACTION = 0.03 # stretches of an edge within the projector's image, grown by this fraction of
                                # its width, are not searched (the pattern's own steps and spill are there)

"""Calibration algorithms on images and points: boards, stereo cameras, projector, pan/tilt head, validation.

Pure computation (numpy, OpenCV, scipy) on top of geometry/; it never imports arproj/. The wizard and the
command line (arproj/wizard, arproj/cli/calibrate.py) drive it with files, devices or the simulated site.

    boards.py        board specs ('chessboard:9x6:0.025', 'charuco:7x5:0.04:0.03'), subpixel detection
    defaults.py      the default board, shared by the wizard and every --board option
    stereo.py        per-camera → stereo → joint refinement, outlier views, coverage feedback
    bundle.py        the joint bundle adjustment (cameras, relative pose, board/wall poses)
    epipolar.py      epipolar error, reprojection RMS, evaluation on held-out pairs
    projector.py     Gray code decoding, Moreno & Taubin local homographies, projector as inverse camera
    head.py          pan/tilt/roll head model fit from projector poses at commanded angles
    validation.py    projected grids, measured landing points vs the calibration's prediction
"""

"""Defaults the calibration commands and the wizard share; a light module, so the command line can name them
without importing OpenCV."""

# The board the wizard asks for and every --board option defaults to: 80 mm squares (a poster-size print) fill
# enough of the image at the 1.3-1.8 m the boards are held at for a rig that works ~2 m from the wall, as on
# the simulated site. OpenCV's sample images (../shared/data) are of an A4 print: pass chessboard:9x6:0.025.
DEFAULT_BOARD = "chessboard:9x6:0.08"

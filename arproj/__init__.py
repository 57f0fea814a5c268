"""arproj: find what is hidden inside a wall and project it back onto that wall, undistorted.

Application layer: the CLI, the simulated site, the calibration wizard, the projection session, the benchmarks
and the demo. It uses the libraries beside it, which never import it: geometry ← {devices, scanner, calibration,
wallpose, render} ← mapping ← arproj (checked by tests/test_layers.py).
"""

__version__ = "0.1.0"

"""arproj: find what is hidden inside a wall and project it back onto that wall, undistorted.

Application layer: the CLI, the renderer, the simulated site, the projection session and the benchmarks.
Data flows one way: scanner → mapping → arproj, with calibration beside it; geometry underneath all.
"""

__version__ = "0.1.0"

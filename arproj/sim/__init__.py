"""The simulated site: a room with walls, the projection robot (3-DOF head, projector, stereo cameras, 2D
laser), a Kinect-like range camera, and the exact truth of everything. See arproj/sim/site.py.

    from arproj.sim import Site
    site = Site.build(seed=0)          # default scene: arproj/sim/scenes/default.yaml
"""

from arproj.sim.room import Target, Wall
from arproj.sim.scene import default_scene, load_scene
from arproj.sim.site import LaserScan, Photo, RangeImage, Site, Truth

__all__ = ["LaserScan", "Photo", "RangeImage", "Site", "Target", "Truth", "Wall", "default_scene",
           "load_scene"]

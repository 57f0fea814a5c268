"""In-wall mapping: occupancy grids on the wall, sensor fusion, frame stitching, surface meshes, objects.

Data flows scanner → mapping → arproj: this package reads scan logs and wall files from `scanner` and
arrays (range images, laser points) from anyone, and never imports `arproj`.

Modules:
    grid        occupancy grid on the wall surface (ROS nav_msgs/OccupancyGrid metadata), log-odds and
                signal layers per sensor, vectorised inverse sensor model
    fusion      classification of detections with the sensors' cross-sensitivity
    map_object  the object type (MapObject) the steps below pass on
    background  the empty wall's robust level and noise in a signal map, z-scores over it
    objects     pipes and cables as polylines, fasteners as points, studs and cavities as outlines
    stitching   per-frame wall plane (RANSAC + least squares) and frame alignment by weighted linear
                least squares, with in-wall features as extra constraints
    surface     triangle meshes from range images, merged views, recognised wall planes
    texture     the in-wall map baked as an RGBA texture in wall coordinates
    export      wall.glb, objects.json, map PNG, signal plots, DXF
    sparse      lines of sparse (adaptive) scans from the passes' 1-D peaks, linked by RANSAC
    frame_features  in-wall features shared by neighbouring frames, as stitching constraints
    scandata    a scan as arrays (ScanData), the pipeline's input
    pipeline    scan log → map → objects (what `arproj map` runs)
    evaluate    objects against a wall file's truth (recall, precision, position/angle error, classes)
    simscan     quick simulated raster scans of wall files (scanner's sensor model) for tests and benchmarks
    tolerances  every numeric tolerance of the package
"""

"""The projection session at the drilling site: the in-wall map pre-warped for the beamer, aimed with the
pan/tilt head, registered from a projected pattern, verified in a closed loop and guarded by a safety gate.

Modules:
    wallmap       wall.glb + objects.json (the mapping's exports) or a wall file's truth → WallMap
    overlays      classes, colours, legend, safety bands, DIN 18015-3 zones, drill-point check, warning frame
    projection    MapProjector: the overlays as the mesh's texture, rendered with the projector's intrinsics
    registration  wall frame from the measured plane, rays to the wall, expected error, closed-loop marks
    gate          evidence → show the map or a warning (and why); stereo triangulation; laser scan matching
    session       ProjectionSession: aim, estimate, verify, decide, show
    robot_io      the simulated robot (site + Pelco-D head simulator) and real hardware behind one interface
    output        beamer window (fullscreen, own process), PNG sequence, memory
    evaluate      ground truth of the registration on the simulated site (benchmark, tests)
    scenarios     degraded scenes rendered on the simulated site for the safety gate (benchmark, tests)
"""

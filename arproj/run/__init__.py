"""What the commands run: one function per job, shared by the command, the demo and the benchmarks.

A command in `arproj/cli/` reads its options, calls one of these and prints what it returns; `arproj demo`
(`arproj/demo.py`) and the benchmarks (`arproj/bench/`) call the same functions, so a scan, a projection
session or a wall-pose measurement is set up in one place only.

Modules:
    scan       a wall by file or shipped name; a scan on the simulated site (serial device simulators or
               in-process), into a new or resumed log; scan and map in one call (`arproj scan`, demo, benches)
    project    what `arproj project` runs: the projection session from its options, kept up where it can
    wallpose   what `arproj wallpose` runs: the wall's pose measured once from the projected pattern
"""

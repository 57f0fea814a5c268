"""Scanning subsystem: wall files, the wall scanner's sensor model, serial devices (GRBL xy drives, wall
scanner) and their simulators, scan planning (dense raster and adaptive) and the crash-safe SQLite scan log.

Data flows one way: scanner -> mapping -> arproj. Nothing here imports mapping/ or arproj/.
"""

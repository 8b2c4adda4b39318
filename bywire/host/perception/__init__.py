"""Perception (seed 000 sections 4-6): what the car sees through its 64-beam LIDAR.

`scan` holds one revolution of points and the readers of recorded ones; the occupancy grid, the
objects tracked on it and the lane markers are modules of their own beside it. Everything here is
pure numpy/scipy on arrays, fed by the host's LIDAR input or by a recorded scan, and tested alone.
"""

"""Navigation in unstructured environments (seed 000 Sec. 10): configuration-space obstacles by FFT
(`cspace`), hybrid A* on the one-track model (`primitives`, `hybrid_astar`) guided by the Reeds-Shepp
metric and the obstacle-aware free-space distance (`reeds_shepp`, `heuristics`), on any occupancy grid
(`grid_map`). Pure functions of their inputs: the planner is a library first, the Zone states its user.
"""

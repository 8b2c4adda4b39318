"""Cooperative platooning (seed 003, sections III-V): follow control, platoon strategy and
string-stability evaluation. Pure functions here; the host modules that use them come with the
V2V link and the world model."""

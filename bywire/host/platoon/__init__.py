"""Cooperative platooning (seed 003, sections III-V): follow control, platoon strategy and
string-stability evaluation. Pure functions here; the host modules that use them are
`host.modules.control.platoon` and `host.modules.estimation.world_model`."""

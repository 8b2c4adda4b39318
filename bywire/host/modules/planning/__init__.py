"""The host's planning: the driver's commands (the mission script) and the urban behaviour of seed 000
sections 8-9 on an RNDF/MDF."""

"""Road networks and missions of the DARPA Urban Challenge (seed 000 section 8): RNDF/MDF, graph, route."""

"""Road networks and missions of the DARPA Urban Challenge (seed 000 section 8): RNDF/MDF, graph, route.

Modules: `rndf` / `mdf` (readers; `errors`, `ids`, `tokens`), `geo` (local metric frame), `path` (smooth
sampled paths: projection, stubs, connectors), `graph` (the geometric graph with annotations and
blockades), `lane_index` (which lane an object is on), `route` (mission planning and re-planning),
`roadnet_cli` (`bywire rndf check`, `bywire mission plan`), `bench` (`bywire bench roadnet`).  Nothing is
imported here: the command line stays fast, the heavy modules load when used.
"""

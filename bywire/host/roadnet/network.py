"""An urban mission as the car drives it: the RNDF's road graph (splined lanes, the MDF's speed limits)
and the MDF's checkpoints resolved on it (seed 000 section 7; DARPA's RNDF and MDF formats)."""

from __future__ import annotations

from pathlib import Path

from bywire.host.roadnet.graph import RoadGraph, build_graph
from bywire.host.roadnet.mdf import ResolvedMission, load_mdf, resolve_mission
from bywire.host.roadnet.rndf import load_rndf


def load_network(rndf: str | Path, mdf: str | Path) -> tuple[RoadGraph, ResolvedMission]:
    """The graph and the resolved mission of an RNDF/MDF pair (file:line errors of the parsers;
    FileNotFoundError naming a missing file)."""
    for f in (rndf, mdf):
        if not Path(f).is_file():
            raise FileNotFoundError(f"no such file {f}")
    net = load_rndf(str(rndf))
    mission = resolve_mission(net, load_mdf(str(mdf)))
    return build_graph(net, mission), mission

"""Shared pieces of the roadnet tests: where the real RNDF/MDF files are, which RNDF each MDF belongs to,
cached parses and graphs (a graph of the VAIL network takes a second or two to build), and a small
synthetic network in local metres whose routes are known by hand, and a small RNDF/MDF with the real
files' quirks as changes of it (the parser's table tests and the fuzzer share them).  No tests in here."""

from __future__ import annotations

import functools
from collections.abc import Callable
from pathlib import Path

import pytest
from shared_data import shared_data_dir

from bywire.host.roadnet.graph import RoadGraph, build_graph
from bywire.host.roadnet.mdf import Mission, ResolvedMission, load_mdf, resolve_mission
from bywire.host.roadnet.rndf import RoadNetwork, load_rndf, parse_rndf

RNDF_DIR = shared_data_dir() / "rndf"


def data_files() -> list[Path]:
    """Every RNDF and MDF of the shared data (not the spec folder), or [] where the data is absent."""
    if not RNDF_DIR.is_dir():
        return []
    return sorted(p for p in RNDF_DIR.glob("*/*") if p.parent.name != "spec" and p.is_file())


def is_mdf(path: Path) -> bool:
    return "mdf" in path.name.lower()


# The RNDF each MDF of the shared data is written for (from the folder, SOURCES.md and the MDF's "RNDF"
# line; the NQE practice MDFs name no RNDF - their checkpoints pick the practice network with or without
# its parking spots).
MDF_TO_RNDF: dict[str, str] = {
    "darpa_sample/Sample_MDF.txt": "darpa_sample/Sample_RNDF.txt",
    "darpa_nqe/nqe_a_mdf.mdf": "darpa_nqe/nqe_rndf.rdf",
    "darpa_nqe/nqe_b1_mdf.mdf": "darpa_nqe/nqe_rndf.rdf",
    "darpa_nqe/nqe_b2_mdf.mdf": "darpa_nqe/nqe_rndf.rdf",
    "darpa_nqe/nqe_c_mdf.mdf": "darpa_nqe/nqe_rndf.rdf",
    "darpa_nqe/nqe_practice_rndf_area_1_parking.mdf": "darpa_nqe/nqe_practice_rndf_area_1_parking.rdf",
    "darpa_nqe/nqe_practice_rndf_area_1_zoneBlockage.mdf": "darpa_nqe/nqe_practice_rndf_area_1.rdf",
    "utexas/swri_site_visit.mdf": "utexas/swri_site_visit.rndf",
    "utexas/prc_large_obstacle.mdf": "utexas/prc_large_obstacle.rndf",
    "stanford/VAIL_mdf.txt": "stanford/VAIL_rndf_20091020.txt",
    "stanford/shoreline_trafficcircle_8_mdf.txt": "stanford/shoreline_trafficcircle_8_rndf.txt",
    "stanford/shortloop_mdf.txt": "stanford/shortloop_rndf.txt",
    "cornell_samples/Sample2.mdf": "cornell_samples/Sample2.rndf",
    "cornell_samples/Sample3.mdf": "cornell_samples/Sample3.rndf",
    "cornell_samples/Sample4.mdf": "cornell_samples/Sample4.rndf",
    "cornell_samples/Sample6.mdf": "cornell_samples/Sample6.rndf",
}

# Real pairs whose MDF asks for a checkpoint its RNDF does not have (the files were written for other
# revisions of each other): the documented MdfError, at this MDF line, for this checkpoint.
#  - Cornell Sample2.mdf lists checkpoints 1..12; Sample2.rndf puts checkpoint 5 on a waypoint that does
#    not exist (1.1.18 of a 2-point lane, dropped with a warning) and has no checkpoint 10.
#  - Stanford shortloop_mdf.txt (9/19/2006) wants checkpoints 1 and 2; shortloop_rndf.txt (3/26/2007) has 1.
INCONSISTENT_PAIRS: dict[str, tuple[int, int]] = {
    "cornell_samples/Sample2.mdf": (10, 5),
    "stanford/shortloop_mdf.txt": (8, 2),
}


def need_data() -> Path:
    if not RNDF_DIR.is_dir():
        pytest.skip(f"shared road network data not found at {RNDF_DIR}")
    return RNDF_DIR


@functools.cache
def network(rel: str) -> RoadNetwork:
    return load_rndf(need_data() / rel)


@functools.cache
def mission(rel: str) -> Mission:
    return load_mdf(need_data() / rel)


@functools.cache
def resolved(rel_mdf: str) -> ResolvedMission:
    return resolve_mission(network(MDF_TO_RNDF[rel_mdf]), mission(rel_mdf))


@functools.cache
def graph(rel: str) -> RoadGraph:
    """A graph per RNDF, without speed limits. Tests that block edges must unblock them again."""
    return build_graph(network(rel))


# -- a synthetic network in local metres (x east, y north) --------------------------------------------
#
#   segment 1: a straight two-lane road along y = 0, lane 1.1 eastbound at y = -2 (right-hand traffic),
#              lane 1.2 westbound at y = +2, waypoints every 50 m from x = 0 to x = 200.
#   segment 2: a second eastbound lane 2.1 continuing lane 1.1 after x = 200 to x = 400 (y = -2),
#              checkpoint 2 at its end.
#   segment 3: a detour 3.1 from (200, -2) north-east over (300, 100) back to (400, -2), which is
#              longer but has a higher speed limit in MISSION below.
#   segment 4: a two-lane eastbound road (4.1 at y = -50, 4.2 at y = -53.5) for lane changes.
#   zone 5:   a square lot entered from 4.1's end, left toward 1.2, one spot with checkpoint 5.
SYNTHETIC_RNDF = """RNDF_name\tsynthetic
num_segments\t4
num_zones\t1
format_version\t1.0
creation_date\ttoday
segment\t1
num_lanes\t2
segment_name\tMain_St
lane\t1.1
num_waypoints\t5
lane_width\t12
left_boundary\tdouble_yellow
right_boundary\tsolid_white
checkpoint\t1.1.1\t1
exit\t1.1.5\t2.1.1
exit\t1.1.5\t3.1.1
1.1.1\t0\t-2
1.1.2\t50\t-2
1.1.3\t100\t-2
1.1.4\t150\t-2
1.1.5\t200\t-2
end_lane
lane\t1.2
num_waypoints\t5
lane_width\t12
left_boundary\tdouble_yellow
checkpoint\t1.2.5\t3
1.2.1\t200\t2
1.2.2\t150\t2
1.2.3\t100\t2
1.2.4\t50\t2
1.2.5\t0\t2
end_lane
end_segment
segment\t2
num_lanes\t1
lane\t2.1
num_waypoints\t3
lane_width\t12
stop\t2.1.3
checkpoint\t2.1.3\t2
2.1.1\t210\t-2
2.1.2\t300\t-2
2.1.3\t400\t-2
end_lane
end_segment
segment\t3
num_lanes\t1
lane\t3.1
num_waypoints\t3
exit\t3.1.3\t2.1.3
3.1.1\t210\t5
3.1.2\t300\t100
3.1.3\t390\t5
end_lane
end_segment
segment\t4
num_lanes\t2
lane\t4.1
num_waypoints\t5
lane_width\t12
right_boundary\tbroken_white
exit\t4.1.5\t5.0.1
4.1.1\t0\t-50
4.1.2\t50\t-50
4.1.3\t100\t-50
4.1.4\t150\t-50
4.1.5\t200\t-50
end_lane
lane\t4.2
num_waypoints\t5
lane_width\t12
left_boundary\tbroken_white
checkpoint\t4.2.5\t4
exit\t4.2.5\t5.0.1
4.2.1\t0\t-53.5
4.2.2\t50\t-53.5
4.2.3\t100\t-53.5
4.2.4\t150\t-53.5
4.2.5\t200\t-53.5
end_lane
end_segment
zone\t5
num_spots\t1
zone_name\tLot
perimeter\t5.0
num_perimeterpoints\t4
exit\t5.0.4\t1.2.1
5.0.1\t210\t-48
5.0.2\t260\t-48
5.0.3\t260\t-8
5.0.4\t210\t-8
end_perimeter
spot\t5.1
spot_width\t10
checkpoint\t5.1.2\t5
5.1.1\t230\t-30
5.1.2\t230\t-20
end_spot
end_zone
end_file
"""


def synthetic_network() -> RoadNetwork:
    return parse_rndf(SYNTHETIC_RNDF, "synthetic.rndf", coordinates="local_m")


def synthetic_mission_text(checkpoints: list[int], limits: dict[int, tuple[int, int]]) -> str:
    body = "\n".join(str(c) for c in checkpoints)
    lim = "\n".join(f"{k}\t{lo}\t{hi}" for k, (lo, hi) in limits.items())
    return (
        f"MDF_name\tsynthetic_mdf\nRNDF\tsynthetic\ncheckpoints\nnum_checkpoints\t{len(checkpoints)}\n{body}\n"
        f"end_checkpoints\nspeed_limits\nnum_speed_limits\t{len(limits)}\n{lim}\nend_speed_limits\nend_file\n"
    )


# -- a small RNDF and MDF, the real files' quirks as changes of it, and line edits for broken files ------

MINI = """RNDF_name\tmini
num_segments\t2
num_zones\t1
format_version\t1.0
creation_date\t4/3/2007
segment\t1
num_lanes\t1
segment_name\tFirst_St
lane\t1.1
num_waypoints\t3
lane_width\t12
left_boundary\tdouble_yellow
checkpoint\t1.1.3\t1
stop\t1.1.3
exit\t1.1.3\t2.1.1
1.1.1\t37.000000\t-122.000000
1.1.2\t37.000100\t-122.000000
1.1.3\t37.000200\t-122.000000
end_lane
end_segment
segment\t2
num_lanes\t1
lane\t2.1
num_waypoints\t2
exit\t2.1.2\t3.0.1
2.1.1\t37.000300\t-122.000000
2.1.2\t37.000400\t-122.000000
end_lane
end_segment
zone\t3
num_spots\t1
zone_name\tLot
perimeter\t3.0
num_perimeterpoints\t3
exit\t3.0.2\t1.1.1
3.0.1\t37.000500\t-122.000000
3.0.2\t37.000500\t-122.000100
3.0.3\t37.000600\t-122.000050
end_perimeter
spot\t3.1
spot_width\t10
checkpoint\t3.1.2\t2
3.1.1\t37.000520\t-122.000050
3.1.2\t37.000540\t-122.000050
end_spot
end_zone
end_file
"""

MINI_MDF = """MDF_name\tmini_mdf
RNDF\tmini
format_version\t1.0
creation_date\t30-Jan-07
checkpoints
num_checkpoints\t3
1
2
1
end_checkpoints
speed_limits
num_speed_limits\t3
1\t5\t30
2\t0\t20
3\t0\t0
end_speed_limits
end_file
"""


def line_of(text: str, needle: str, nth: int = 0) -> int:
    """1-based number of the (nth) line that starts with `needle`."""
    hits = [i for i, ln in enumerate(text.splitlines(), start=1) if ln.startswith(needle)]
    return hits[nth]


def delete_line(text: str, needle: str) -> str:
    return "\n".join(ln for ln in text.splitlines() if not ln.startswith(needle)) + "\n"


def insert_after(text: str, needle: str, new: str) -> str:
    out = []
    for ln in text.splitlines():
        out.append(ln)
        if ln.startswith(needle):
            out.append(new)
    return "\n".join(out) + "\n"


Quirk = Callable[[str], str]

QUIRKS: dict[str, tuple[Quirk, int]] = {
    # name: (change of MINI, number of warnings it must produce)
    "crlf": (lambda t: t.replace("\n", "\r\n"), 0),
    "lone_cr": (lambda t: t.replace("\n", "\r"), 0),
    "spaces_and_trailing_tabs": (lambda t: t.replace("\t", "  \t ").replace("\n", "\t\t\n"), 0),
    "comment_lines_and_line_ends": (
        lambda t: (
            "/* change log */\n/* more */\n"
            + t.replace("end_lane\n", "end_lane /* done */\n").replace(
                "end_file\n", "end_file\n/* trailer */\n"
            )
        ),
        0,
    ),
    "multi_line_comment": (
        lambda t: t.replace("end_segment\n", "end_segment /* a\ncomment\nspanning */\n", 1),
        0,
    ),
    "comment_glued_to_token": (lambda t: t.replace("end_file\n", "end_file/*x*/\n"), 0),
    "no_final_newline": (lambda t: t.rstrip("\n"), 0),
    "header_order_checkpoint_first": (
        lambda t: t.replace(
            "num_waypoints\t3\nlane_width\t12\nleft_boundary\tdouble_yellow\ncheckpoint\t1.1.3\t1\n",
            "checkpoint\t1.1.3\t1\nlane_width\t12\nnum_waypoints\t3\nleft_boundary\tdouble_yellow\n",
        ),
        0,
    ),
    "solid_yellow": (lambda t: t.replace("double_yellow", "solid_yellow"), 0),
    "num_spots_0_without_spots": (
        lambda t: t[: t.index("spot\t3.1")].replace("num_spots\t1", "num_spots\t0") + "end_zone\nend_file\n",
        0,
    ),
    "segment_count_disagrees": (lambda t: t.replace("num_segments\t2", "num_segments\t5"), 1),
    "lane_count_disagrees": (lambda t: t.replace("num_lanes\t1", "num_lanes\t2", 1), 1),
    "waypoint_count_disagrees": (lambda t: t.replace("num_waypoints\t3", "num_waypoints\t4"), 1),
    "spot_count_disagrees": (lambda t: t.replace("num_spots\t1", "num_spots\t6"), 1),
    "waypoints_not_from_1": (
        lambda t: (
            t.replace("1.1.1\t", "1.1.4\t")
            .replace("1.1.2\t", "1.1.5\t")
            .replace("1.1.3\t", "1.1.6\t")
            .replace("checkpoint\t1.1.6", "checkpoint\t1.1.6")
            .replace("1.1.3", "1.1.6")
            .replace("1.1.1", "1.1.4")
        ),
        1,
    ),
    "duplicate_exit": (lambda t: insert_after(t, "exit\t1.1.3", "exit\t1.1.3\t2.1.1"), 1),
    "duplicate_stop": (lambda t: insert_after(t, "stop\t1.1.3", "stop\t1.1.3"), 1),
    "spot_without_checkpoint": (lambda t: delete_line(t, "checkpoint\t3.1.2"), 1),
    "dangling_exit_dropped": (lambda t: insert_after(t, "exit\t1.1.3", "exit\t1.1.3\t2.1.9"), 1),
    "checkpoint_in_other_lanes_header": (
        lambda t: insert_after(delete_line(t, "checkpoint\t1.1.3"), "exit\t2.1.2", "checkpoint\t1.1.3\t1"),
        1,
    ),
    "v11_extension_keywords": (
        lambda t: (
            t.replace("num_zones\t1\n", "num_zones\t1\nnum_intersections\t1\n")
            .replace(
                "segment_name\tFirst_St\n", "segment_name\tFirst_St\nnum_crosswalks\t1\nspeed_limit\t25.00\n"
            )
            .replace(
                "lane_width\t12\n",
                "lane_width\t12\nlane_type\tcar_lane\ncross\t1.1.2\t1.1\tstop\nlight\t1.1.3\t4.1\n",
            )
            .replace(
                "end_lane\nend_segment\nsegment\t2",
                "end_lane\ncrosswalk\t1.1\ncrosswalk_width\t10\ncrosswalk_p1\t37.0001\t-122.00001\n"
                "crosswalk_p2\t37.0001\t-121.99999\nend_crosswalk\nend_segment\nsegment\t2",
            )
            .replace(
                "end_zone\nend_file",
                "end_zone\nintersection\t4\nnum_trafficlights\t1\ntrafficlight\t4.1\ngroup_id\t1\n"
                "position\t37.0002\t-122.0\t3.0\nend_trafficlight\nend_intersection\nend_file",
            )
        ),
        0,
    ),
}


def network_content(net: RoadNetwork) -> tuple[object, ...]:
    """What a network says, without the source line numbers."""
    return (
        sorted((w.id, w.lat, w.lon) for w in net.waypoints()),
        sorted((e.exit, e.entry) for e in net.exits()),
        sorted((n, c.waypoint) for n, c in net.checkpoints.items()),
        sorted(s.waypoint for lane in net.lanes() for s in lane.stops),
        [(lane.id, lane.width_m, lane.left_boundary, lane.right_boundary) for lane in net.lanes()],
        [(s.id, s.name) for s in net.segments] + [(z.id, z.name) for z in net.zones],
    )

"""RNDF / MDF readers (urban driving, seed 000): every shared real file, a table test per real-file quirk, a
table of broken files with the line and the expectation each error must name, strict mode, and MDF <-> RNDF
resolution."""

from __future__ import annotations

import math
import pickle
from pathlib import Path

import pytest
from roadnet_helpers import (
    INCONSISTENT_PAIRS,
    MDF_TO_RNDF,
    MINI,
    MINI_MDF,
    QUIRKS,
    RNDF_DIR,
    Quirk,
    data_files,
    delete_line,
    insert_after,
    is_mdf,
    line_of,
    mission,
    network,
    network_content,
)

from bywire.host.roadnet.errors import MdfError, RndfError, RoadnetError
from bywire.host.roadnet.ids import LaneId, WaypointId
from bywire.host.roadnet.mdf import load_mdf, parse_mdf, resolve_mission
from bywire.host.roadnet.rndf import FEET_TO_M, MPH_TO_MPS, RoadNetwork, load_rndf, parse_rndf

# ---------------------------------------------------------------------------------------------- real files


REAL = data_files()


@pytest.mark.parametrize("path", REAL, ids=[str(p.relative_to(RNDF_DIR)) for p in REAL])
def test_every_shared_file_parses(path: Path) -> None:
    if is_mdf(path):
        m = load_mdf(path)
        assert m.checkpoints and all(c.number >= 1 for c in m.checkpoints)
        assert all(
            lim.max_mps is None or 0 < lim.max_mps <= 30 * MPH_TO_MPS for lim in m.speed_limits.values()
        )
    else:
        net = load_rndf(path)
        assert net.segments and all(lane.waypoints for lane in net.lanes())
        # every reference that survived points at something that exists
        for ex in net.exits():
            assert net.has_waypoint(ex.exit) and net.has_waypoint(ex.entry)
        for cp in net.checkpoints.values():
            assert net.has_waypoint(cp.waypoint)
        for lane in net.lanes():
            assert all(net.has_waypoint(s.waypoint) for s in lane.stops)


def test_data_folder_present_or_skip() -> None:
    if not REAL:
        pytest.skip(f"shared road network data not found at {RNDF_DIR}")
    mdfs = {str(p.relative_to(RNDF_DIR)) for p in REAL if is_mdf(p)}
    assert mdfs == set(MDF_TO_RNDF), "every shared MDF has its RNDF in MDF_TO_RNDF"


@pytest.mark.parametrize("mdf", sorted(MDF_TO_RNDF))
def test_every_mdf_resolves_in_its_rndf(mdf: str) -> None:
    net, m = network(MDF_TO_RNDF[mdf]), mission(mdf)
    if mdf in INCONSISTENT_PAIRS:
        line, number = INCONSISTENT_PAIRS[mdf]
        with pytest.raises(MdfError) as info:
            resolve_mission(net, m)
        assert (info.value.line, info.value.path) == (line, m.path)
        assert f"checkpoint {number} is not defined" in info.value.expected
        return
    res = resolve_mission(net, m)
    assert len(res.waypoints) == len(m.checkpoints)
    for number, wid in zip(m.checkpoint_numbers, res.waypoints, strict=True):
        assert net.checkpoint_waypoint(number) == wid


def test_known_real_file_contents() -> None:
    net = network("darpa_sample/Sample_RNDF.txt")
    assert (net.name, net.format_version, net.creation_date) == ("Sample_RNDF.txt", "1.0", "4/3/2007")
    assert (len(net.segments), len(net.zones), net.coordinates) == (13, 1, "wgs84")
    lane = net.lane(LaneId(1, 1))
    assert lane.width_m == pytest.approx(12 * FEET_TO_M)
    assert lane.left_boundary == "double_yellow"
    assert net.segment(1).name == "Michigan_Ave"
    zone = net.zone(14)
    assert len(zone.spots) == 6 and zone.spots[0].waypoints[1].id == WaypointId(14, 1, 2)
    assert zone.spots[0].checkpoint is not None and zone.spots[0].checkpoint.waypoint == WaypointId(14, 1, 2)
    assert len(net.checkpoints) == 17  # SOURCES.md: "17 checkpoints"
    nqe = network("darpa_nqe/nqe_rndf.rdf")
    assert (len(nqe.segments), len(nqe.zones)) == (41, 3)
    assert nqe.zone(42).declared_spots == 0 and nqe.zone(42).spots == ()  # num_spots 0
    m = mission("darpa_sample/Sample_MDF.txt")
    assert len(m.checkpoints) == 18 and len(m.speed_limits) == 14  # SOURCES.md
    assert m.speed_limits[1].max_mps == pytest.approx(25 * 0.44704)  # "1 10 25"
    assert m.speed_limits[1].min_mps == pytest.approx(10 * 0.44704) and m.speed_limits[2].min_mps is None


def test_vail_extension_items() -> None:
    net = network("stanford/VAIL_rndf_20091020.txt")
    assert net.format_version == "1.1" and net.declared_intersections == 1
    (inter,) = net.intersections
    assert inter.id == 63 and [tl.id for tl in inter.traffic_lights] == [LaneId(63, k) for k in (1, 2, 3)]
    assert inter.traffic_lights[0].group_id == 1 and inter.traffic_lights[2].group_id is None
    assert inter.traffic_lights[0].z_m == pytest.approx(22.3)
    lane = net.lane(LaneId(2, 1))
    assert lane.crosswalk_uses[0].crosswalk == LaneId(2, 1) and lane.crosswalk_uses[0].kind == "stop"
    assert lane.traffic_light_uses[0].light == LaneId(63, 3)
    assert net.segment(2).crosswalks[0].width_m == pytest.approx(10 * FEET_TO_M)
    assert net.segment(10).speed_limit_mps == pytest.approx(25 * MPH_TO_MPS)
    assert net.lane(LaneId(59, 1)).lane_type == "bike_lane"


# ---------------------------------------------------------------------------------------------- quirks


def test_mini_parses_cleanly() -> None:
    net = parse_rndf(MINI, "mini.rndf")
    assert net.warnings == ()
    assert net.checkpoint_waypoint(1) == WaypointId(1, 1, 3)
    assert net.checkpoint_waypoint(2) == WaypointId(3, 1, 2)
    assert [(str(e.exit), str(e.entry)) for e in net.exits()] == [
        ("1.1.3", "2.1.1"),
        ("2.1.2", "3.0.1"),
        ("3.0.2", "1.1.1"),
    ]
    assert net.waypoint(WaypointId(1, 1, 2)).lat == pytest.approx(37.0001)
    assert net.area_ids == (1, 2, 3)


@pytest.mark.parametrize("name", sorted(QUIRKS))
def test_quirk_is_accepted(name: str) -> None:
    change, n_warnings = QUIRKS[name]
    text = change(MINI)
    net = parse_rndf(text, "q.rndf")
    assert len(net.warnings) == n_warnings, [str(w) for w in net.warnings]
    assert all(str(w).startswith("q.rndf:") and ": warning: " in str(w) for w in net.warnings)
    assert net.has_waypoint(WaypointId(2, 1, 1))
    if n_warnings:
        with pytest.raises(RndfError) as info:
            parse_rndf(text, "q.rndf", strict=True)
        assert "(strict)" in info.value.expected or "expected an existing" in info.value.expected


def test_quirks_lose_nothing() -> None:
    plain = parse_rndf(MINI, "a")
    assert plain.segments == parse_rndf(QUIRKS["crlf"][0](MINI), "a").segments  # same lines too
    for name in (
        "crlf",
        "lone_cr",
        "spaces_and_trailing_tabs",
        "comment_lines_and_line_ends",
        "no_final_newline",
        "multi_line_comment",
        "comment_glued_to_token",
        "header_order_checkpoint_first",
    ):
        assert network_content(parse_rndf(QUIRKS[name][0](MINI), "a")) == network_content(plain), name


def test_dangling_exit_is_dropped_with_its_line() -> None:
    text = insert_after(MINI, "exit\t1.1.3", "exit\t1.1.3\t2.1.9")
    net = parse_rndf(text, "d.rndf")
    (w,) = net.warnings
    assert w.line == line_of(text, "exit\t1.1.3\t2.1.9") and "2.1.9 is not defined" in w.message
    assert [str(e.entry) for e in net.lane(LaneId(1, 1)).exits] == ["2.1.1"]
    with pytest.raises(RndfError) as info:
        parse_rndf(text, "d.rndf", strict=True)
    assert (
        info.value.line == w.line
        and info.value.expected == "expected an existing waypoint, 2.1.9 is not defined"
    )


def test_local_metre_files_are_detected() -> None:
    net = network("cornell_samples/Sample3.rndf")
    assert net.coordinates == "local_m"
    assert any("local metres" in w.message for w in net.warnings)
    assert network("darpa_sample/Sample_RNDF.txt").coordinates == "wgs84"
    # forced either way
    assert parse_rndf(MINI, coordinates="local_m").coordinates == "local_m"


def test_units_at_the_edge() -> None:
    net = parse_rndf(MINI)
    assert net.lane(LaneId(1, 1)).width_m == pytest.approx(3.6576)
    assert net.zone(3).spots[0].width_m == pytest.approx(3.048)
    assert parse_rndf(MINI.replace("lane_width\t12", "lane_width\t0")).lane(LaneId(1, 1)).width_m is None
    m = parse_mdf(MINI_MDF)
    assert m.speed_limits[1].min_mps == pytest.approx(5 * 0.44704)
    assert m.speed_limits[1].max_mps == pytest.approx(13.4112)
    assert m.speed_limits[2].min_mps is None and m.speed_limits[3].max_mps is None


# ---------------------------------------------------------------------------------------------- errors

Broken = tuple[Quirk, str, str]  # change, line to expect (startswith of that line or "EOF"), text in message

BROKEN: dict[str, Broken] = {
    "missing_end_file": (lambda t: t.replace("end_file\n", ""), "EOF", "expected segment, zone or end_file"),
    "truncated_in_lane": (lambda t: t[: t.index("1.1.3\t37")], "EOF", "expected end_lane of lane 1.1"),
    "missing_end_lane": (
        lambda t: t.replace("end_lane\nend_segment\nsegment\t2", "end_segment\nsegment\t2"),
        "end_segment",
        "expected end_lane of lane 1.1 before 'end_segment'",
    ),
    "text_after_end_file": (
        lambda t: t + "segment\t9\n",
        "segment\t9",
        "expected nothing but comments after end_file",
    ),
    "not_an_rndf": (lambda t: "MDF_name\tx\n" + t, "MDF_name", "expected RNDF_name at the start"),
    "missing_num_zones": (lambda t: delete_line(t, "num_zones"), "segment\t1", "expected num_zones"),
    "waypoint_of_other_lane": (
        lambda t: t.replace("1.1.2\t37", "2.1.7\t37"),
        "2.1.7",
        "expected a point of 1.1 (1.1.P, P >= 1) or an end marker, found 2.1.7",
    ),
    "swapped_waypoints": (
        lambda t: (
            t.replace("1.1.2\t37.000100", "1.1.X")
            .replace("1.1.3\t37.000200", "1.1.2\t37.000100")
            .replace("1.1.X", "1.1.3\t37.000200")
        ),
        "1.1.2",
        "numbered after 1.1.3",
    ),
    "waypoint_zero": (lambda t: t.replace("1.1.1\t37", "1.1.0\t37"), "1.1.0", "P >= 1"),
    "duplicate_waypoint": (
        lambda t: t.replace("1.1.3\t37", "1.1.2\t37"),
        "1.1.2\t37.000200",
        "numbered after 1.1.2",
    ),
    "duplicate_segment": (
        lambda t: t.replace("segment\t2", "segment\t1"),
        "segment\t1\nnum_lanes\t1\nlane\t2",
        "1 is already used on line",
    ),
    "zone_id_reuses_segment": (
        lambda t: t.replace("zone\t3", "zone\t2").replace("3.", "2."),
        "zone",
        "2 is already used",
    ),
    "duplicate_lane": (
        lambda t: t.replace(
            "lane\t2.1", "lane\t2.1\nnum_waypoints\t1\n2.1.1\t37.0003\t-122.0\nend_lane\nlane\t2.1"
        ),
        "lane\t2.1\nnum_waypoints\t2",
        "2.1 is already used",
    ),
    "duplicate_checkpoint_number": (
        lambda t: t.replace("checkpoint\t3.1.2\t2", "checkpoint\t3.1.2\t1"),
        "checkpoint\t3.1.2",
        "1 is already used on line",
    ),
    "bad_boundary": (
        lambda t: t.replace("double_yellow", "dashed_pink"),
        "left_boundary",
        "expected a boundary",
    ),
    "bad_number": (
        lambda t: t.replace("37.000100", "37.0x0100"),
        "1.1.2",
        "expected a decimal number as latitude",
    ),
    "nan_coordinate": (lambda t: t.replace("37.000100", "nan"), "1.1.2", "expected a decimal number"),
    "huge_coordinate": (lambda t: t.replace("37.000100", "1e999"), "1.1.2", "expected a finite number"),
    "latitude_out_of_range": (
        lambda t: t.replace("37.000100", "97.000100"),
        "1.1.2",
        "expected latitude in [-90, 90]",
    ),
    "missing_longitude": (
        lambda t: t.replace("37.000100\t-122.000000", "37.000100"),
        "1.1.2",
        "expected '1.1.2 <latitude> <longitude>'",
    ),
    "unknown_keyword": (
        lambda t: t.replace("stop\t1.1.3", "stpo\t1.1.3"),
        "stpo",
        "expected a lane header keyword",
    ),
    "exit_missing_entry": (
        lambda t: t.replace("exit\t1.1.3\t2.1.1", "exit\t1.1.3"),
        "exit\t1.1.3",
        "expected 'exit <exit waypoint> <entry waypoint>'",
    ),
    "exit_to_itself": (
        lambda t: t.replace("exit\t1.1.3\t2.1.1", "exit\t1.1.3\t1.1.3"),
        "exit\t1.1.3",
        "other than the exit waypoint",
    ),
    "negative_count": (
        lambda t: t.replace("num_lanes\t1", "num_lanes\t-1", 1),
        "num_lanes",
        "non-negative integer",
    ),
    "spot_with_three_points": (
        lambda t: insert_after(t, "3.1.2\t37", "3.1.3\t37.00056\t-122.00005"),
        "3.1.3",
        "expected the spot's waypoints 3.1.1 then 3.1.2",
    ),
    "spot_with_one_point": (lambda t: delete_line(t, "3.1.2\t37"), "spot\t3.1", "expected two waypoints"),
    "perimeter_of_other_zone": (
        lambda t: t.replace("perimeter\t3.0", "perimeter\t4.0"),
        "perimeter",
        "expected perimeter 3.0 of zone 3",
    ),
    "lane_without_waypoints": (
        lambda t: t.replace("2.1.1\t37.000300\t-122.000000\n2.1.2\t37.000400\t-122.000000\n", ""),
        "lane\t2.1",
        "expected at least one waypoint in lane 2.1",
    ),
    "unterminated_comment": (
        lambda t: t.replace("end_segment\nsegment\t2", "end_segment /* oops\nsegment\t2"),
        "end_segment /*",
        "expected '*/'",
    ),
    "non_ascii_byte": (
        lambda t: t.replace("First_St", "First_Stra\u00dfe"),
        "segment_name",
        "expected ASCII text",
    ),
    "nul_byte": (lambda t: t.replace("end_zone", "end_\x00zone"), "end_\x00", "found byte 0x00"),
    "one_num_lanes_too_many": (
        lambda t: insert_after(t, "num_lanes", "num_lanes\t1"),
        "num_lanes\t1\nsegment_name",
        "expected one 'num_lanes' in this block",
    ),
    "cross_unknown_kind": (
        lambda t: t.replace("stop\t1.1.3", "cross\t1.1.3\t1.1\tmaybe"),
        "cross",
        "expected 'stop' or 'incoming'",
    ),
}


def _expected_line(text: str, where: str) -> int:
    lines = text.replace("\r\n", "\n").split("\n")
    if where == "EOF":
        return len(lines) - (1 if text.endswith("\n") else 0)
    first, *rest = where.split("\n")
    for i, ln in enumerate(lines):
        if ln.startswith(first) and all(lines[i + 1 + k].startswith(r) for k, r in enumerate(rest)):
            return i + 1
    raise AssertionError(f"{where!r} not in the text")


@pytest.mark.parametrize("name", sorted(BROKEN))
def test_broken_file_names_line_and_expectation(name: str) -> None:
    change, where, message = BROKEN[name]
    text = change(MINI)
    with pytest.raises(RndfError) as info:
        parse_rndf(text, "bad.rndf")
    err = info.value
    assert message in err.expected, str(err)
    assert err.line == _expected_line(text, where), str(err)
    assert str(err) == f"bad.rndf:{err.line}: {err.expected}"
    assert err.expected.startswith("expected ")


def test_errors_pickle_with_their_fields() -> None:
    err = RndfError("f.rndf", 12, "expected end_lane")
    back = pickle.loads(pickle.dumps(err))
    assert (back.path, back.line, back.expected, str(back)) == ("f.rndf", 12, "expected end_lane", str(err))
    assert isinstance(back, RoadnetError) and isinstance(back, ValueError)


def test_unreadable_file_is_a_roadnet_error(tmp_path: Path) -> None:
    with pytest.raises(RndfError) as info:
        load_rndf(tmp_path / "missing.rndf")
    assert info.value.line == 0 and "readable" in info.value.expected
    with pytest.raises(MdfError):
        load_mdf(tmp_path / "missing.mdf")


# ---------------------------------------------------------------------------------------------- MDF


def test_mdf_known_contents() -> None:
    m = parse_mdf(MINI_MDF, "m.mdf")
    assert m.checkpoint_numbers == (1, 2, 1)
    assert [c.line for c in m.checkpoints] == [7, 8, 9]
    assert (m.name, m.rndf_name, m.format_version, m.creation_date) == (
        "mini_mdf",
        "mini",
        "1.0",
        "30-Jan-07",
    )
    assert m.warnings == ()
    res = resolve_mission(parse_rndf(MINI), m)
    assert res.waypoints == (WaypointId(1, 1, 3), WaypointId(3, 1, 2), WaypointId(1, 1, 3))
    assert res.warnings == ()


def test_team_tool_header_is_a_warning() -> None:
    text = MINI_MDF.replace("MDF_name\tmini_mdf", "MDF_name\t").replace("RNDF\tmini", "RNDF_name\t")
    m = parse_mdf(text, "t.mdf")
    assert [w.line for w in m.warnings] == [1, 2]
    with pytest.raises(MdfError) as info:
        parse_mdf(text, "t.mdf", strict=True)
    assert info.value.line == 1


def test_mdf_without_end_markers_only_when_its_count_vouches() -> None:
    cut = MINI_MDF[: MINI_MDF.index("end_speed_limits")]
    m = parse_mdf(cut, "c.mdf")  # the real utexas/prc_large_obstacle.mdf case
    assert len(m.speed_limits) == 3 and "without end_speed_limits" in m.warnings[-1].message
    # the same but the last line incomplete (cut inside it): an error, not a smaller mission
    with pytest.raises(MdfError) as info:
        parse_mdf(cut.rstrip("\n")[:-1], "c.mdf")
    assert "end_speed_limits" in info.value.expected
    # one speed limit missing: the count no longer vouches
    with pytest.raises(MdfError):
        parse_mdf(cut.replace("3\t0\t0\n", ""), "c.mdf")
    # a real file of that kind
    real = mission("utexas/prc_large_obstacle.mdf")
    assert len(real.speed_limits) == 8 and real.warnings


MDF_BROKEN: dict[str, tuple[Quirk, int, str]] = {
    "min_above_max": (lambda t: t.replace("1\t5\t30", "1\t35\t30"), 13, "minimum speed <= maximum speed"),
    "duplicate_limit": (lambda t: t.replace("2\t0\t20", "1\t0\t20"), 14, "1 already has one on line 13"),
    "negative_speed": (lambda t: t.replace("2\t0\t20", "2\t-1\t20"), 14, "expected speeds >= 0 mph"),
    "zero_checkpoint": (lambda t: t.replace("\n2\n", "\n0\n"), 8, "positive integer checkpoint number"),
    "checkpoint_with_junk": (lambda t: t.replace("\n2\n", "\n2 x\n"), 8, "one per line"),
    "no_checkpoints": (lambda t: t.replace("1\n2\n1\n", ""), 7, "at least one checkpoint"),
    "missing_end_file": (lambda t: t.replace("end_file\n", ""), 16, "expected end_file"),
    "speed_limit_short": (
        lambda t: t.replace("2\t0\t20", "2\t0"),
        14,
        "<segment or zone id> <min mph> <max mph>",
    ),
    "missing_rndf_line": (lambda t: delete_line(t, "RNDF\t"), 2, "expected RNDF <name of the RNDF>"),
}


@pytest.mark.parametrize("name", sorted(MDF_BROKEN))
def test_broken_mdf_names_line_and_expectation(name: str) -> None:
    change, line, message = MDF_BROKEN[name]
    with pytest.raises(MdfError) as info:
        parse_mdf(change(MINI_MDF), "bad.mdf")
    assert message in info.value.expected and info.value.line == line, str(info.value)
    assert str(info.value).startswith(f"bad.mdf:{line}: expected")


def test_resolve_mission_names_the_mdf_line() -> None:
    text = MINI_MDF.replace("\n2\n1\nend", "\n2\n7\nend")
    with pytest.raises(MdfError) as info:
        resolve_mission(parse_rndf(MINI, "mini.rndf"), parse_mdf(text, "x.mdf"))
    assert (info.value.path, info.value.line) == ("x.mdf", 9)
    assert "checkpoint 7 is not defined" in info.value.expected and "mini.rndf" in info.value.expected


def test_resolve_mission_warns_about_speed_limit_ids() -> None:
    text = MINI_MDF.replace("3\t0\t0", "9\t0\t10")
    res = resolve_mission(parse_rndf(MINI), parse_mdf(text, "w.mdf"))
    assert any("9, not a segment or zone" in w.message for w in res.warnings)
    assert any("no speed limit for segments/zones 3" in w.message for w in res.warnings)


def test_ids_parse_and_print() -> None:
    assert WaypointId.parse("17.2.5") == WaypointId(17, 2, 5) and str(WaypointId(17, 2, 5)) == "17.2.5"
    assert LaneId.parse("14.0") == LaneId(14, 0) and WaypointId(14, 0, 3).is_perimeter
    assert sorted([WaypointId(1, 10, 1), WaypointId(1, 9, 1)]) == [WaypointId(1, 9, 1), WaypointId(1, 10, 1)]
    for bad in ("1.2", "1.2.3.4", " 1.2.3", "1.2.x", "", "1..3", "-1.2.3", "1234567890.1.1"):
        with pytest.raises(ValueError):
            WaypointId.parse(bad)
    assert WaypointId(3, 1, 2).lane_id == LaneId(3, 1) and LaneId(3, 1).waypoint(2) == WaypointId(3, 1, 2)


def test_network_lookups() -> None:
    net: RoadNetwork = parse_rndf(MINI)
    with pytest.raises(KeyError):
        net.waypoint(WaypointId(9, 9, 9))
    with pytest.raises(KeyError):
        net.checkpoint_waypoint(99)
    assert net.segment(2).lanes[0].id == LaneId(2, 1)
    assert sum(1 for _ in net.waypoints()) == 3 + 2 + 3 + 2
    assert math.isclose(net.zone(3).perimeter.points[2].lon, -122.00005)

"""Property tests of the RNDF / MDF readers on truncated and mutated real files (urban driving, seed 000).

Whatever the damage, the reader returns a network (mission) or raises the documented RndfError (MdfError):
never another exception.  Beyond that, a damaged file must not pass as a different valid one unless it
really is one:

- a file cut anywhere (byte or line) parses to the same content as the whole file, or fails: `end_file`
  must come last, so only comments and blanks may be lost;
- a deleted line fails, warns (its warnings differ from the whole file's), or was an optional item whose
  absence makes another valid file (a stop sign, an exit, a lane width, ...);
- a duplicated line fails, warns, changes nothing, or was an optional item now also in another block
  (a boundary copied into a lane that had none: valid again);
- a moved (swapped) line fails, warns, or changes nothing - except two items of one kind trading places;
- any parsed result is consistent: every exit, checkpoint and stop names an existing waypoint.

Each property runs DEFAULT_EXAMPLES examples by default and LONG_EXAMPLES as the ``_long`` twin behind
``-m slow``.
"""

from __future__ import annotations

from collections.abc import Callable

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from roadnet_helpers import MINI, MINI_MDF, QUIRKS, RNDF_DIR, network_content

from bywire.host.roadnet.errors import MdfError, RndfError
from bywire.host.roadnet.mdf import Mission, parse_mdf
from bywire.host.roadnet.rndf import RoadNetwork, parse_rndf
from bywire.host.roadnet.tokens import decode

SMALL_RNDFS = (
    "utexas/prc_small.rndf",
    "utexas/swri_site_visit.rndf",
    "darpa_nqe/nqe_practice_rndf_area_1_parking.rdf",
    "darpa_nqe/estop_rndf.rdf",
    "stanford/shortloop_rndf.txt",
)
MDFS = (
    "darpa_sample/Sample_MDF.txt",
    "darpa_nqe/nqe_c_mdf.mdf",
    "utexas/prc_large_obstacle.mdf",
    "darpa_nqe/nqe_practice_rndf_area_1_parking.mdf",
    "cornell_samples/Sample6.mdf",
)

# Lines whose removal leaves another valid file (an item the format makes optional).
OPTIONAL_RNDF = {
    "format_version",
    "creation_date",
    "segment_name",
    "zone_name",
    "lane_width",
    "left_boundary",
    "right_boundary",
    "checkpoint",
    "stop",
    "exit",
    "spot_width",
    "num_intersections",
    "num_crosswalks",
    "speed_limit",
    "lane_type",
    "cross",
    "light",
    "group_id",
    "crosswalk_width",
    "num_trafficlights",
    "offroad",
}
OPTIONAL_MDF = {"format_version", "creation_date"}

DEFAULT_EXAMPLES = 40  # per property: the bounded run (a few seconds)
LONG_EXAMPLES = 2000  # the campaign behind -m slow


def _texts(names: tuple[str, ...], extra: tuple[str, ...]) -> list[tuple[str, str]]:
    out = [(f"inline{i}", t) for i, t in enumerate(extra)]
    if RNDF_DIR.is_dir():
        out += [(n, decode((RNDF_DIR / n).read_bytes())) for n in names]
    return out


RNDF_TEXTS = _texts(SMALL_RNDFS, (MINI, QUIRKS["v11_extension_keywords"][0](MINI)))
MDF_TEXTS = _texts(MDFS, (MINI_MDF,))


def _rndf(text: str) -> RoadNetwork | None:
    try:
        net = parse_rndf(text, "fuzz.rndf")
    except RndfError as err:
        assert err.path == "fuzz.rndf" and err.expected.startswith("expected"), str(err)
        assert str(err).startswith(f"fuzz.rndf:{err.line}: expected")
        return None
    _consistent(net)
    return net


def _mdf(text: str) -> Mission | None:
    try:
        return parse_mdf(text, "fuzz.mdf")
    except MdfError as err:
        assert err.path == "fuzz.mdf" and err.expected.startswith("expected"), str(err)
        return None


def _consistent(net: RoadNetwork) -> None:
    for ex in net.exits():
        assert net.has_waypoint(ex.exit) and net.has_waypoint(ex.entry)
    for cp in net.checkpoints.values():
        assert net.has_waypoint(cp.waypoint)
    for lane in net.lanes():
        assert lane.waypoints
        assert all(net.has_waypoint(s.waypoint) for s in lane.stops)
        idx = [w.id.number for w in lane.waypoints]
        assert idx == sorted(set(idx))


def _warned(damaged: RoadNetwork | Mission, full: RoadNetwork | Mission) -> bool:
    """The damaged file's warnings say something the whole file's do not (line numbers aside)."""
    return sorted(w.message for w in damaged.warnings) != sorted(w.message for w in full.warnings)


def _mission_content(m: Mission) -> tuple[object, ...]:
    return (m.checkpoint_numbers, sorted((k, v.min_mps, v.max_mps) for k, v in m.speed_limits.items()))


def _keyword(line: str) -> str:
    code = line.split("/*")[0].split()
    return code[0] if code else ""


TOKENS = st.one_of(
    st.sampled_from(
        [
            "",
            "0",
            "1",
            "-1",
            "1.1",
            "1.1.1",
            "99.99.99",
            "1.0.1",
            "end_lane",
            "end_file",
            "nan",
            "1e999",
            "37.5",
            "-122.0",
            "lane",
            "segment",
            "zone",
            "exit",
            "/*",
            "*/",
            "\x00",
            "\u00e9",
            "9" * 30,
            "1_0",
        ]
    ),
    st.text(alphabet="0123456789.-+eE", max_size=12),
    st.text(max_size=6),
)


def _property_tests(examples: int) -> tuple[Callable[..., None], ...]:
    """The property tests with `examples` hypothesis examples each (bounded by default, long when slow)."""
    fuzz = settings(
        max_examples=examples, deadline=None, suppress_health_check=[HealthCheck.too_slow], derandomize=True
    )

    @fuzz
    @given(case=st.integers(0, len(RNDF_TEXTS) - 1), cut=st.floats(0.0, 1.0), at_line=st.booleans())
    def test_truncated_rndf_is_an_error_or_the_same_network(case: int, cut: float, at_line: bool) -> None:
        text = RNDF_TEXTS[case][1]
        full = _rndf(text)
        assert full is not None
        if at_line:
            lines = text.splitlines(keepends=True)
            piece = "".join(lines[: int(cut * len(lines))])
        else:
            piece = text[: int(cut * len(text))]
        net = _rndf(piece)
        if net is not None:
            assert network_content(net) == network_content(full) and "end_file" in piece

    @fuzz
    @given(case=st.integers(0, len(RNDF_TEXTS) - 1), data=st.data())
    def test_deleted_line_fails_warns_or_was_optional(case: int, data: st.DataObject) -> None:
        text = RNDF_TEXTS[case][1]
        full = _rndf(text)
        assert full is not None
        lines = text.splitlines(keepends=True)
        i = data.draw(st.integers(0, len(lines) - 1))
        net = _rndf("".join(lines[:i] + lines[i + 1 :]))
        if net is None or _warned(net, full) or network_content(net) == network_content(full):
            return
        assert _keyword(lines[i]) in OPTIONAL_RNDF, f"deleting {lines[i]!r} silently changed the network"

    @fuzz
    @given(case=st.integers(0, len(RNDF_TEXTS) - 1), data=st.data(), duplicate=st.booleans())
    def test_duplicated_or_swapped_lines_fail_warn_or_change_nothing(
        case: int, data: st.DataObject, duplicate: bool
    ) -> None:
        text = RNDF_TEXTS[case][1]
        full = _rndf(text)
        assert full is not None
        lines = text.splitlines(keepends=True)
        i = data.draw(st.integers(0, len(lines) - 1))
        j = data.draw(st.integers(0, len(lines) - 1))
        out = list(lines)
        if duplicate:
            out.insert(j, lines[i] if lines[i].endswith("\n") else lines[i] + "\n")
        else:
            out[i], out[j] = out[j], out[i]
        net = _rndf("".join(out))
        if net is None or _warned(net, full) or network_content(net) == network_content(full):
            return
        if duplicate:  # an optional item copied into a block that lacked it: a valid, different file
            assert _keyword(lines[i]) in OPTIONAL_RNDF, (
                f"duplicating {lines[i]!r} silently changed the network"
            )
        else:  # two items of one kind trading places (two lane widths): a valid, different file
            same_kind = _keyword(lines[i]) == _keyword(lines[j]) and _keyword(lines[i]) in OPTIONAL_RNDF
            assert same_kind, f"swapping {lines[i]!r} / {lines[j]!r} silently changed the network"

    @fuzz
    @given(case=st.integers(0, len(RNDF_TEXTS) - 1), data=st.data(), token=TOKENS)
    def test_mutated_token_gives_a_network_or_the_error(case: int, data: st.DataObject, token: str) -> None:
        text = RNDF_TEXTS[case][1]
        start, end = data.draw(st.sampled_from(_token_spans(text)))
        _rndf(text[:start] + token + text[end:])

    @fuzz
    @given(case=st.integers(0, len(RNDF_TEXTS) - 1), data=st.data())
    def test_random_bytes_give_a_network_or_the_error(case: int, data: st.DataObject) -> None:
        text = RNDF_TEXTS[case][1]
        raw = bytearray(text.encode("latin-1"))
        for _ in range(data.draw(st.integers(1, 4))):
            raw[data.draw(st.integers(0, len(raw) - 1))] = data.draw(st.integers(0, 255))
        _rndf(decode(bytes(raw)))

    @fuzz
    @given(blob=st.binary(max_size=300))
    def test_arbitrary_bytes_are_a_clean_error(blob: bytes) -> None:
        _rndf(decode(blob))
        _mdf(decode(blob))

    @fuzz
    @given(case=st.integers(0, len(MDF_TEXTS) - 1), cut=st.floats(0.0, 1.0), at_line=st.booleans())
    def test_truncated_mdf_is_an_error_or_the_same_mission(case: int, cut: float, at_line: bool) -> None:
        text = MDF_TEXTS[case][1]
        full = _mdf(text)
        assert full is not None
        if at_line:
            lines = text.splitlines(keepends=True)
            piece = "".join(lines[: int(cut * len(lines))])
        else:
            piece = text[: int(cut * len(text))]
        m = _mdf(piece)
        if m is not None:
            assert _mission_content(m) == _mission_content(full)

    @fuzz
    @given(
        case=st.integers(0, len(MDF_TEXTS) - 1),
        data=st.data(),
        op=st.sampled_from(["delete", "duplicate", "swap", "token"]),
        token=TOKENS,
    )
    def test_mutated_mdf_fails_warns_or_is_really_valid(
        case: int, data: st.DataObject, op: str, token: str
    ) -> None:
        text = MDF_TEXTS[case][1]
        full = _mdf(text)
        assert full is not None
        lines = text.splitlines(keepends=True)
        i = data.draw(st.integers(0, len(lines) - 1))
        j = data.draw(st.integers(0, len(lines) - 1))
        out = list(lines)
        if op == "delete":
            del out[i]
        elif op == "duplicate":
            out.insert(j, lines[i] if lines[i].endswith("\n") else lines[i] + "\n")
        elif op == "swap":
            out[i], out[j] = out[j], out[i]
        else:
            start, end = data.draw(st.sampled_from(_token_spans(text)))
            _mdf(text[:start] + token + text[end:])
            return
        m = _mdf("".join(out))
        if m is None or _warned(m, full) or _mission_content(m) == _mission_content(full):
            return
        ki, kj = _keyword(lines[i]), _keyword(lines[j])
        if op == "delete":
            assert ki in OPTIONAL_MDF, f"deleting {lines[i]!r} silently changed the mission"
        elif op == "swap":
            # two checkpoints or two speed limits trading places: a valid, different mission
            both_numbers = ki.isdigit() and kj.isdigit()
            assert both_numbers, f"swapping {lines[i]!r} / {lines[j]!r} silently changed the mission"
        else:
            raise AssertionError(f"duplicating {lines[i]!r} silently changed the mission")

    return (
        test_truncated_rndf_is_an_error_or_the_same_network,
        test_deleted_line_fails_warns_or_was_optional,
        test_duplicated_or_swapped_lines_fail_warn_or_change_nothing,
        test_mutated_token_gives_a_network_or_the_error,
        test_random_bytes_give_a_network_or_the_error,
        test_arbitrary_bytes_are_a_clean_error,
        test_truncated_mdf_is_an_error_or_the_same_mission,
        test_mutated_mdf_fails_warns_or_is_really_valid,
    )


(
    test_truncated_rndf_is_an_error_or_the_same_network,
    test_deleted_line_fails_warns_or_was_optional,
    test_duplicated_or_swapped_lines_fail_warn_or_change_nothing,
    test_mutated_token_gives_a_network_or_the_error,
    test_random_bytes_give_a_network_or_the_error,
    test_arbitrary_bytes_are_a_clean_error,
    test_truncated_mdf_is_an_error_or_the_same_mission,
    test_mutated_mdf_fails_warns_or_is_really_valid,
) = _property_tests(DEFAULT_EXAMPLES)

(
    test_truncated_rndf_is_an_error_or_the_same_network_long,
    test_deleted_line_fails_warns_or_was_optional_long,
    test_duplicated_or_swapped_lines_fail_warn_or_change_nothing_long,
    test_mutated_token_gives_a_network_or_the_error_long,
    test_random_bytes_give_a_network_or_the_error_long,
    test_arbitrary_bytes_are_a_clean_error_long,
    test_truncated_mdf_is_an_error_or_the_same_mission_long,
    test_mutated_mdf_fails_warns_or_is_really_valid_long,
) = (pytest.mark.slow(t) for t in _property_tests(LONG_EXAMPLES))


def _token_spans(text: str) -> list[tuple[int, int]]:
    spans = []
    pos = 0
    for tok in text.split():
        start = text.index(tok, pos)
        spans.append((start, start + len(tok)))
        pos = start + len(tok)
    return spans


def test_fuzz_inputs_exist() -> None:
    assert len(RNDF_TEXTS) >= 2 and len(MDF_TEXTS) >= 1
    if not RNDF_DIR.is_dir():
        pytest.skip(f"shared road network data not found at {RNDF_DIR}; fuzzing the inline texts only")
    assert all((RNDF_DIR / n).exists() for n in SMALL_RNDFS + MDFS)

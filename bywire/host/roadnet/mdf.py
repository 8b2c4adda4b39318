"""Mission Data File reader (DARPA, "RNDF and MDF Formats", May 12 2006, sec. 3; seed 000 sec. 8).

`load_mdf(path)` / `parse_mdf(text, path)` return a `Mission`: the checkpoint numbers to visit in order
(repeats allowed; the last one is the finish line, where the car must stop) and a speed limit per segment
or zone, converted from the file's miles per hour to m/s here, at the edge (``0`` = undefined -> None).
`resolve_mission(network, mission)` maps the checkpoints onto the RNDF's waypoints and raises `MdfError`
naming the MDF line of the first checkpoint the RNDF does not have.

Tolerated, with a `ParseWarning` (errors with ``strict=True``):

- ``RNDF_name`` where the format has ``RNDF``, and an empty ``MDF_name`` (Cornell's team tool; the NQE
  practice MDFs).
- ``num_checkpoints`` / ``num_speed_limits`` that disagree with the lists (Cornell's ``Sample6``: 12
  declared, 2 listed).
- A file that ends right after its last speed limit, without ``end_speed_limits`` and ``end_file`` (UT
  Austin's ``prc_large_obstacle.mdf``) - but only when the last line is complete (the file ends with a line
  break) and both lists have exactly the declared number of entries, i.e. the file's own counts vouch
  that nothing was cut (a file whose checkpoint count is off cannot vouch with its other count: Cornell's
  ``Sample6`` declares 1 speed limit and lists 27, so cut after the first it would pass).  Any other
  missing end marker is an error, so a truncated file does not pass as a shorter mission.

Speed limits: ``min > max`` (both defined) and a second limit for the same id are errors; limits may be
decimal numbers (the format says integers; a decimal loses nothing).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from .errors import MdfError, ParseWarning
from .ids import WaypointId
from .rndf import MPH_TO_MPS, RoadNetwork
from .tokens import Cursor, Line, decode


@dataclass(frozen=True)
class MissionCheckpoint:
    number: int
    line: int


@dataclass(frozen=True)
class SpeedLimit:
    """Limits of one segment or zone, m/s; None where the MDF says 0 (undefined)."""

    area_id: int
    min_mps: float | None
    max_mps: float | None
    line: int


@dataclass(frozen=True)
class Mission:
    path: str
    name: str
    rndf_name: str
    format_version: str | None
    creation_date: str | None
    checkpoints: tuple[MissionCheckpoint, ...]
    speed_limits: dict[int, SpeedLimit]
    declared_checkpoints: int | None = None
    declared_speed_limits: int | None = None
    warnings: tuple[ParseWarning, ...] = field(default=(), compare=False)

    @property
    def checkpoint_numbers(self) -> tuple[int, ...]:
        return tuple(c.number for c in self.checkpoints)


@dataclass(frozen=True)
class ResolvedMission:
    """A mission checked against its network: checkpoint waypoints in visiting order."""

    mission: Mission
    waypoints: tuple[WaypointId, ...]
    warnings: tuple[ParseWarning, ...] = ()

    @property
    def checkpoint_numbers(self) -> tuple[int, ...]:
        return self.mission.checkpoint_numbers


_HEADER = ("format_version", "creation_date")


class _MdfParser:
    def __init__(self, text: str, path: str, strict: bool) -> None:
        self.c = Cursor(text, path, MdfError)
        self.path = path
        self.strict = strict
        self.ends_with_newline = text.endswith(("\n", "\r"))
        self.warnings: list[ParseWarning] = []

    def warn(self, line: int, message: str) -> None:
        if self.strict:
            raise MdfError(self.path, line, f"expected no format quirks (strict): {message}")
        self.warnings.append(ParseWarning(self.path, line, message))

    def _keyword(self, expected: str) -> Line:
        line = self.c.take(expected)
        if line.keyword != expected:
            raise self.c.unexpected(line, expected)
        return line

    def _count(self, keyword: str) -> tuple[int, int]:
        line = self._keyword(keyword)
        (tok,) = self.c.args(line, 1, f"{keyword} <count>")
        return self.c.integer(line, tok, keyword), line.number

    def parse(self) -> Mission:
        c = self.c
        first = c.take("MDF_name")
        if first.keyword != "MDF_name":
            raise c.unexpected(first, "MDF_name at the start of an MDF")
        name = c.text(first)
        if not name:
            self.warn(first.number, "empty MDF_name")
        rline = c.take("RNDF <name of the RNDF>")
        if rline.keyword == "RNDF_name":
            self.warn(rline.number, "'RNDF_name' where the format has 'RNDF'")
        elif rline.keyword != "RNDF":
            raise c.unexpected(rline, "RNDF <name of the RNDF> after MDF_name")
        rndf_name = c.text(rline)
        header: dict[str, str] = {}
        while (line := c.peek()) is not None and line.keyword in _HEADER:
            c.take("")
            if line.keyword in header:
                raise c.fail(line, f"expected one '{line.keyword}' in the file header, found a second")
            header[line.keyword] = c.text(line)
        cp_line = self._keyword("checkpoints")
        c.args(cp_line, 0, "checkpoints")
        declared_cps, declared_cps_line = self._count("num_checkpoints")
        checkpoints: list[MissionCheckpoint] = []
        while True:
            line = c.take("a checkpoint number or end_checkpoints")
            if line.keyword == "end_checkpoints":
                c.args(line, 0, "end_checkpoints")
                break
            c.args(line, 0, "<checkpoint number> (one per line)")
            number = c.integer(line, line.keyword, "checkpoint number (or end_checkpoints)", minimum=1)
            checkpoints.append(MissionCheckpoint(number, line.number))
        if not checkpoints:
            raise c.fail(line, "expected at least one checkpoint before end_checkpoints")
        if declared_cps != len(checkpoints):
            self.warn(
                declared_cps_line, f"num_checkpoints is {declared_cps}, the list has {len(checkpoints)}"
            )
        sl_line = self._keyword("speed_limits")
        c.args(sl_line, 0, "speed_limits")
        declared_sls, declared_sls_line = self._count("num_speed_limits")
        limits: dict[int, SpeedLimit] = {}
        while True:
            line_or_none = c.peek()
            counts_agree = len(limits) == declared_sls and len(checkpoints) == declared_cps
            if line_or_none is None and counts_agree and self.ends_with_newline:
                self.warn(
                    c.eof_line, "file ends after its last speed limit, without end_speed_limits/end_file"
                )
                return self._mission(name, rndf_name, header, checkpoints, limits, declared_cps, declared_sls)
            line = c.take("a speed limit '<segment or zone id> <min mph> <max mph>' or end_speed_limits")
            if line.keyword == "end_speed_limits":
                c.args(line, 0, "end_speed_limits")
                break
            limit = self._speed_limit(line)
            if limit.area_id in limits:
                raise c.fail(
                    line,
                    f"expected one speed limit per segment/zone, {limit.area_id} already has one on "
                    f"line {limits[limit.area_id].line}",
                )
            limits[limit.area_id] = limit
        if declared_sls != len(limits):
            self.warn(declared_sls_line, f"num_speed_limits is {declared_sls}, the list has {len(limits)}")
        end = c.take("end_file")
        if end.keyword != "end_file":
            raise c.unexpected(end, "end_file after end_speed_limits")
        c.args(end, 0, "end_file")
        extra = c.peek()
        if extra is not None:
            raise c.fail(extra, f"expected nothing but comments after end_file (line {end.number})")
        return self._mission(name, rndf_name, header, checkpoints, limits, declared_cps, declared_sls)

    def _speed_limit(self, line: Line) -> SpeedLimit:
        c = self.c
        if len(line.tokens) != 3:
            raise c.fail(line, "expected '<segment or zone id> <min mph> <max mph>' or end_speed_limits")
        area = c.integer(line, line.tokens[0], "segment/zone id", minimum=1)
        lo = c.number(line, line.tokens[1], "as minimum speed (mph)")
        hi = c.number(line, line.tokens[2], "as maximum speed (mph)")
        if lo < 0 or hi < 0:
            raise c.fail(line, "expected speeds >= 0 mph (0 = undefined)")
        if lo > 0 and hi > 0 and lo > hi:
            raise c.fail(line, f"expected minimum speed <= maximum speed, found {lo:g} > {hi:g} mph")
        return SpeedLimit(
            area, lo * MPH_TO_MPS if lo > 0 else None, hi * MPH_TO_MPS if hi > 0 else None, line.number
        )

    def _mission(
        self,
        name: str,
        rndf_name: str,
        header: dict[str, str],
        checkpoints: list[MissionCheckpoint],
        limits: dict[int, SpeedLimit],
        declared_cps: int,
        declared_sls: int,
    ) -> Mission:
        return Mission(
            path=self.path,
            name=name,
            rndf_name=rndf_name,
            format_version=header.get("format_version"),
            creation_date=header.get("creation_date"),
            checkpoints=tuple(checkpoints),
            speed_limits=limits,
            declared_checkpoints=declared_cps,
            declared_speed_limits=declared_sls,
            warnings=tuple(sorted(self.warnings, key=lambda w: w.line)),
        )


def parse_mdf(text: str, path: str = "<mdf>", strict: bool = False) -> Mission:
    """Parse MDF text; `path` is only used in messages. Raises `MdfError`."""
    return _MdfParser(text, path, strict).parse()


def load_mdf(path: str | Path, strict: bool = False) -> Mission:
    """Read and parse an MDF file (bytes decoded as Latin-1; non-ASCII outside comments is an error)."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise MdfError(str(p), 0, f"expected a readable file ({exc.strerror or exc})") from None
    return parse_mdf(decode(data), str(p), strict)


def resolve_mission(network: RoadNetwork, mission: Mission) -> ResolvedMission:
    """Checkpoint waypoints of `mission` in `network`; `MdfError` at the MDF line of an unknown checkpoint.

    Speed limits for ids that are neither segment nor zone of the network, and segments or zones without
    a limit (planning then uses its default speed), come back as warnings.
    """
    known = network.checkpoints
    waypoints: list[WaypointId] = []
    for cp in mission.checkpoints:
        if cp.number not in known:
            raise MdfError(
                mission.path,
                cp.line,
                f"expected a checkpoint of RNDF {network.name!r} ({network.path}), checkpoint {cp.number} "
                "is not defined there",
            )
        waypoints.append(known[cp.number].waypoint)
    warnings: list[ParseWarning] = []
    areas = set(network.area_ids)
    for limit in mission.speed_limits.values():
        if limit.area_id not in areas:
            warnings.append(
                ParseWarning(
                    mission.path, limit.line, f"speed limit for {limit.area_id}, not a segment or zone"
                )
            )
    missing = sorted(areas - set(mission.speed_limits))
    if missing:
        shown = ", ".join(map(str, missing[:10])) + (", ..." if len(missing) > 10 else "")
        warnings.append(ParseWarning(mission.path, 0, f"no speed limit for segments/zones {shown}"))
    return ResolvedMission(mission, tuple(waypoints), tuple(warnings))

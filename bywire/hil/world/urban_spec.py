"""The scenario's `urban:` section (seed 000): an RNDF/MDF road network, where our car starts, the traffic
on the network's lanes and the perfect-perception object list the host receives.

Parsed as strictly as the rest of a scenario (`hil.scenario`): an unknown key, a wrong type or an
impossible value is refused with the file and the path of the field
(`four_way_stop_1.yaml: urban.vehicles[0].route[1]: '9.9.9' is not a waypoint of cross.rndf`). The
network itself is read by `host.roadnet` (file:line errors) when the world or the host is built.

RNDF/MDF paths are absolute, relative to the scenario file (a scenario re-read from a recording, which has
no folder: relative to the shipped scenarios, hil/scenarios/), or `shared:REL` - resolved against the shared
data root: `$BYWIRE_SHARED_DATA`, else `../shared/data` beside the repository, else `/work/shared/data`
(the shared data is never copied into the repository). Schema and examples: docs/scenarios.md.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bywire.schema import Reader, SchemaError

SHARED_PREFIX = "shared:"
SHARED_ENV = "BYWIRE_SHARED_DATA"
DRIVERS = ("lane", "stuck", "parked")


class UrbanSpecError(SchemaError):
    """An `urban:` section that cannot be simulated, with the file and the path of the field."""


@dataclass(frozen=True)
class UrbanVehicleSpec:
    """A traffic car. `lane`: drives `route` (consecutive RNDF waypoints) at `speed_mps`, stops at the
    stop lines on it and takes its turn first-come-first-served; `stuck`: stands at its place forever (a
    car that never moves); `parked`: stands at (`x_m`, `y_m`, `heading_deg`) or at its route's start."""

    name: str
    driver: str
    route: tuple[str, ...] = ()
    s_m: float = 0.0  # along the route from its first waypoint (negative: before it, straight on)
    at_stop_line: bool = False  # placed with its front bumper 0.3 m before the route's first stop line
    speed_mps: float = 5.0
    v0_mps: float = 0.0
    depart_at_s: float = 0.0  # it does not move before
    stop_at_stops: bool = True
    x_m: float | None = None
    y_m: float | None = None
    heading_deg: float = 0.0
    length_m: float = 4.5
    width_m: float = 1.8
    # parked: not there until our front bumper comes within this distance of it (a box fallen off a
    # truck just ahead); 0: there from the start
    appears_ahead_m: float = 0.0


@dataclass(frozen=True)
class ObjectsSpec:
    """The object list's stand-in for perception: ground truth, with optional noise and latency."""

    rate_hz: float = 10.0
    range_m: float = 120.0
    position_noise_m: float = 0.0
    heading_noise_rad: float = 0.0
    speed_noise_mps: float = 0.0


@dataclass(frozen=True)
class PoseSpec:
    """The ego pose link (RTK-grade or perfect): rate and noise."""

    rate_hz: float = 100.0
    position_noise_m: float = 0.0
    heading_noise_rad: float = 0.0
    # The map's error (seed 000 Sec. 6: "a systematic error of RNDF data in some areas"): the simulated
    # road lies this far (east, north) from where the RNDF has it. The world stays on the RNDF's geometry
    # and reports our pose, and the perfect object list, moved by it: to a host, a constant translation
    # between its map and its position fix cannot be told from a map that is off by it, and the LIDAR
    # sees the world around the car, wherever the car thinks it is.
    map_offset_m: tuple[float, float] = (0.0, 0.0)


@dataclass(frozen=True)
class BuildingSpec:
    """A box standing beside the road (a building; a thin one is a wall), centred at (`x_m`, `y_m`) with
    its length along `heading_deg`. Only the simulated LIDAR sees it (`hil.lidar`): the collision
    bookkeeping and the object list know vehicles, so anything on the road is a `parked` car."""

    x_m: float
    y_m: float
    length_m: float
    width_m: float
    height_m: float = 10.0
    heading_deg: float = 0.0


@dataclass(frozen=True)
class ScenerySpec:
    """What the simulated LIDAR sees besides the road and the vehicles (`hil.lidar.urban_scene`)."""

    # 0: no curbs; else a curb this high along the road's outer edges (AnnieWAY detected curbs as small
    # height steps in the range data, seed 000 Sec. 6; 10-15 cm is a kerb's usual height)
    curb_height_m: float = 0.0
    buildings: tuple[BuildingSpec, ...] = ()


@dataclass(frozen=True)
class LidarSpec:
    """The simulated Velodyne's settings (`hil.lidar.velodyne.SimulatedVelodyne`)."""

    rate_hz: float = 10.0
    azimuth_steps: int = 2000
    range_noise_m: float = 0.02
    dropout_probability: float = 0.02


@dataclass(frozen=True)
class UrbanSpec:
    rndf: str  # resolved absolute path
    mdf: str
    start: str | None  # waypoint id where the rear axle starts (default: the mission's first checkpoint)
    vehicles: tuple[UrbanVehicleSpec, ...]
    objects: ObjectsSpec = ObjectsSpec()
    pose: PoseSpec = PoseSpec()
    trace_hz: float = 10.0
    speed_tolerance_mps: float = 0.5  # a speed-limit violation exceeds the MDF's limit by more than this
    stop_tolerance_m: float = 1.0  # rules 5.2: front bumper within 1 m of the stop line
    ego_length_m: float = 4.77
    ego_width_m: float = 1.82
    scenery: ScenerySpec = ScenerySpec()
    # What the host perceives the other cars by (the scenario's top-level `perception:` key): `perfect`,
    # the world's object list; `lidar`, the simulated Velodyne's revolutions (`hil.lidar`), the object list
    # then carrying our pose only.
    perception: str = "perfect"
    lidar: LidarSpec = LidarSpec()


def shared_data_root() -> Path:
    """`$BYWIRE_SHARED_DATA`, else `../shared/data` beside the repository, else `/work/shared/data`."""
    env = os.environ.get(SHARED_ENV)
    if env:
        return Path(env)
    beside = Path(__file__).resolve().parents[2].parent / "shared" / "data"
    if beside.is_dir():
        return beside
    return Path("/work/shared/data")


def resolve_data_path(value: str, source: str) -> Path:
    """A scenario's RNDF/MDF reference as a path (not checked for existence here)."""
    if value.startswith(SHARED_PREFIX):
        return shared_data_root() / value[len(SHARED_PREFIX) :]
    path = Path(value)
    if not path.is_absolute():
        if Path(source).is_file():
            return Path(source).parent / path
        # a scenario re-read from a recording (replay) has no folder: the shipped scenarios' one
        shipped = Path(__file__).resolve().parents[1] / "scenarios" / path
        if shipped.is_file():
            return shipped
    return path


def _missing(path: Path) -> str:
    return (
        f"no such file {path} (shared data root {shared_data_root()}: set {SHARED_ENV} to where shared/data "
        "is; the shared data is never copied into the repository)"
    )


def _file(r: Reader, key: str) -> str:
    raw = r.string(key)
    path = resolve_data_path(raw, r.source)
    # a `shared:` file is looked for when the run starts (`require_files`): a checkout without the shared
    # data still lists and parses every shipped scenario
    if not raw.startswith(SHARED_PREFIX) and not path.is_file():
        raise r.error(key, f"no such file {path}")
    return str(path)


def require_files(spec: UrbanSpec, source: str, error_type: type[SchemaError] = UrbanSpecError) -> None:
    """Refuse to run without the network's files, naming the file and where shared data is looked for."""
    for key in ("rndf", "mdf"):
        path = Path(getattr(spec, key))
        if not path.is_file():
            raise error_type(source, f"urban.{key}", _missing(path))


def _vehicle(r: Reader) -> UrbanVehicleSpec:
    name = r.string("name")
    driver = r.string("driver", default="lane", choices=DRIVERS)
    raw_route = r.raw("route", []) or []
    if not isinstance(raw_route, list) or not all(isinstance(w, str) for w in raw_route):
        raise r.error("route", f"expected a list of waypoint ids like '1.1.2', got {raw_route!r}")
    kw: dict[str, Any] = {"name": name, "driver": driver, "route": tuple(raw_route)}
    has_xy = r.has("x_m") or r.has("y_m")
    if has_xy:
        kw["x_m"] = r.number("x_m", lo=-1e6, hi=1e6)
        kw["y_m"] = r.number("y_m", lo=-1e6, hi=1e6)
        kw["heading_deg"] = r.number("heading_deg", default=0.0, lo=-360.0, hi=360.0)
        if driver != "parked":
            raise r.error("x_m", "only a parked car is placed by x_m/y_m; others drive a route")
    elif len(raw_route) < 2:
        raise r.error("route", "expected at least two consecutive waypoints (or x_m/y_m for a parked car)")
    kw["s_m"] = r.number("s_m", default=0.0, lo=-1000.0, hi=1e6)
    kw["at_stop_line"] = r.boolean("at_stop_line", False)
    kw["speed_mps"] = r.number("speed_mps", default=5.0, lo=0.0, hi=30.0)
    kw["v0_mps"] = r.number("v0_mps", default=0.0, lo=0.0, hi=30.0)
    kw["depart_at_s"] = r.number("depart_at_s", default=0.0, lo=0.0)
    kw["stop_at_stops"] = r.boolean("stop_at_stops", True)
    kw["length_m"] = r.number("length_m", default=4.5, lo=1.0, hi=25.0)
    kw["width_m"] = r.number("width_m", default=1.8, lo=0.2, hi=3.5)
    kw["appears_ahead_m"] = r.number("appears_ahead_m", default=0.0, lo=0.0, hi=1000.0)
    if kw["appears_ahead_m"] > 0.0 and driver != "parked":
        raise r.error("appears_ahead_m", "only a parked object appears; traffic drives from the start")
    r.finish()
    return UrbanVehicleSpec(**kw)


def _scenery(r: Reader) -> ScenerySpec:
    raw = r.raw("buildings", []) or []
    if not isinstance(raw, list):
        raise r.error("buildings", "expected a list of buildings")
    buildings = []
    for i, item in enumerate(raw):
        b = type(r)(item, r.source, r._p(f"buildings[{i}]"))
        buildings.append(
            BuildingSpec(
                x_m=b.number("x_m", lo=-1e6, hi=1e6),
                y_m=b.number("y_m", lo=-1e6, hi=1e6),
                length_m=b.number("length_m", lo=0.1, hi=1000.0),
                width_m=b.number("width_m", lo=0.1, hi=1000.0),
                height_m=b.number("height_m", default=10.0, lo=0.1, hi=500.0),
                heading_deg=b.number("heading_deg", default=0.0, lo=-360.0, hi=360.0),
            )
        )
        b.finish()
    spec = ScenerySpec(
        curb_height_m=r.number("curb_height_m", default=0.0, lo=0.0, hi=0.5), buildings=tuple(buildings)
    )
    r.finish()
    return spec


def parse_urban(
    data: Any, source: str, path: str = "urban", error_type: type[SchemaError] = UrbanSpecError
) -> UrbanSpec:
    """The `urban:` mapping of a scenario -> `UrbanSpec` (files resolved and checked to exist; waypoint
    ids are checked against the network when it is built: `hil.world.urban.UrbanWorld`)."""
    reader: type[Reader] = type("_UrbanReader", (Reader,), {"error_type": error_type})
    r = reader(data, source, path)
    rndf = _file(r, "rndf")
    mdf = _file(r, "mdf")
    start = r.raw("start")
    if start is not None and not isinstance(start, str):
        raise r.error("start", f"expected a waypoint id like '1.1.1', got {start!r}")
    raw_vehicles = r.raw("vehicles", []) or []
    if not isinstance(raw_vehicles, list):
        raise r.error("vehicles", "expected a list of vehicles")
    vehicles = tuple(
        _vehicle(type(r)(item, source, r._p(f"vehicles[{i}]"))) for i, item in enumerate(raw_vehicles)
    )
    names = [v.name for v in vehicles]
    for i, n in enumerate(names):
        if n in names[:i] or n == "ego":
            raise error_type(source, r._p(f"vehicles[{i}].name"), f"name {n!r} is taken")
    ob = r.sub("objects")
    objects = ObjectsSpec(
        rate_hz=ob.number("rate_hz", default=10.0, lo=1.0, hi=100.0),
        range_m=ob.number("range_m", default=120.0, lo=5.0, hi=500.0),
        position_noise_m=ob.number("position_noise_m", default=0.0, lo=0.0, hi=5.0),
        heading_noise_rad=ob.number("heading_noise_rad", default=0.0, lo=0.0, hi=1.0),
        speed_noise_mps=ob.number("speed_noise_mps", default=0.0, lo=0.0, hi=5.0),
    )
    ob.finish()
    po = r.sub("pose")
    pose = PoseSpec(
        rate_hz=po.number("rate_hz", default=100.0, lo=10.0, hi=100.0),
        position_noise_m=po.number("position_noise_m", default=0.0, lo=0.0, hi=2.0),
        heading_noise_rad=po.number("heading_noise_rad", default=0.0, lo=0.0, hi=0.2),
        map_offset_m=_pair(po, "map_offset_m", 10.0),
    )
    po.finish()
    li = r.sub("lidar")
    lidar = LidarSpec(
        rate_hz=li.number("rate_hz", default=10.0, lo=5.0, hi=20.0),
        azimuth_steps=int(li.number("azimuth_steps", default=2000.0, lo=90.0, hi=4000.0)),
        range_noise_m=li.number("range_noise_m", default=0.02, lo=0.0, hi=1.0),
        dropout_probability=li.number("dropout_probability", default=0.02, lo=0.0, hi=0.9),
    )
    li.finish()
    spec = UrbanSpec(
        rndf=rndf,
        mdf=mdf,
        start=start,
        vehicles=vehicles,
        objects=objects,
        pose=pose,
        trace_hz=r.number("trace_hz", default=10.0, lo=1.0, hi=100.0),
        speed_tolerance_mps=r.number("speed_tolerance_mps", default=0.5, lo=0.0, hi=10.0),
        stop_tolerance_m=r.number("stop_tolerance_m", default=1.0, lo=0.1, hi=10.0),
        scenery=_scenery(r.sub("scenery")),
        lidar=lidar,
    )
    r.finish()
    return spec


def _pair(r: Reader, key: str, limit: float) -> tuple[float, float]:
    raw = r.raw(key, [0.0, 0.0])
    if (
        not isinstance(raw, list | tuple)
        or len(raw) != 2
        or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in raw)
        or not all(abs(float(v)) <= limit for v in raw)
    ):
        raise r.error(key, f"expected [east, north] in metres, each within +-{limit}, got {raw!r}")
    return float(raw[0]), float(raw[1])


__all__ = [
    "BuildingSpec",
    "LidarSpec",
    "ObjectsSpec",
    "PoseSpec",
    "ScenerySpec",
    "UrbanSpec",
    "UrbanSpecError",
    "UrbanVehicleSpec",
    "parse_urban",
    "require_files",
    "resolve_data_path",
    "shared_data_root",
]

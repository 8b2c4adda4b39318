"""A scenario as a host's inputs: the simulator's stand-in for a car's command line (`host.inputs`).

The scenario's `host:` section and its host-side faults (re-arm pulses, STOP requests, a released engage)
become the driver's command script; its road, its RNDF/MDF and its V2V settings become the mission.
The HIL runner and SIL hand the result to the same host agent a car runs.
"""

from __future__ import annotations

import functools
import tomllib
from pathlib import Path

import numpy as np
import yaml

from bywire.hil.scenario import Scenario, parse_scenario
from bywire.host.command_script import CommandScript, Window
from bywire.host.geo import LocalFrame
from bywire.host.inputs import HostInputs
from bywire.host.modules.messages import RunInfo
from bywire.host.replay import car_run_inputs
from bywire.host.world.lanemap import LaneMap, record_lane

DEFAULT_ORIGIN = (51.4708, 5.6230)  # the A270 of GCDC 2011, for a scenario without a world
LANE_MAP_LENGTH_M = 20_000.0


def command_script(scenario: Scenario) -> CommandScript:
    faults = scenario.faults
    return CommandScript(
        mode=scenario.host_mode,
        speed_profile=scenario.speed_profile,
        accel_profile=scenario.accel_profile,
        steer_profile=scenario.steer_profile,
        engage_at_s=scenario.engage_at_s,
        stop_line_m=scenario.stop_line_m,
        rearm_at_s=tuple(f.at_s for f in faults if f.kind == "rearm"),
        stop=tuple(Window(f.at_s, f.duration_s) for f in faults if f.kind == "host_stop"),
        engage_release=tuple(Window(f.at_s, f.duration_s) for f in faults if f.kind == "engage_press"),
        source=scenario.source,
    )


def host_inputs(scenario: Scenario) -> HostInputs:
    world = scenario.world
    return HostInputs(
        commands=command_script(scenario),
        rndf=scenario.urban.rndf if scenario.urban is not None else None,
        mdf=scenario.urban.mdf if scenario.urban is not None else None,
        lane_map=functools.partial(scenario_lane_map, scenario),
        local_frame=functools.partial(scenario_frame, scenario),
        station_id=world.ego.station_id if world is not None else 1,
        v2v_epoch_unix_s=world.v2v.epoch_unix_s if world is not None else HostInputs.v2v_epoch_unix_s,
        duration_s=scenario.duration_s,
        source=scenario.source,
        source_text=_read_text(scenario.source),
    )


def _read_text(path: str) -> str:
    try:
        return Path(path).read_text(encoding="utf-8")
    except OSError:
        return ""  # a scenario built in memory: the recording cannot carry it


def scenario_frame(scenario: Scenario) -> LocalFrame:
    w = scenario.world
    if w is None:
        return LocalFrame(*DEFAULT_ORIGIN)
    return LocalFrame(w.road.origin_lat_deg, w.road.origin_lon_deg)


def scenario_lane_map(scenario: Scenario, map_file: str | None = None) -> LaneMap:
    """The lane map: a file (`LaneMap.load`, e.g. recorded by driving the lane), else recorded from the
    scenario road's right lane (seed 003 IV-A) with the other lanes at their offsets."""
    if map_file:
        return LaneMap.load(Path(map_file))
    frame = scenario_frame(scenario)
    w = scenario.world
    if w is None:
        track = np.array([[0.0, 0.0], [LANE_MAP_LENGTH_M, 0.0]])
        return record_lane(np.linspace(track[0], track[1], 200), frame)
    from bywire.hil.world.road import Road

    road = Road(w.road)
    path = road.lane(0).path
    s = np.arange(0.0, path.length_m + 1e-9, 1.0)
    x, y, _, _ = path.sample(s)
    lanemap = record_lane(np.column_stack((x, y)), frame, smooth_m=0.5)
    for k in range(1, w.road.lanes):
        lanemap = lanemap.with_offset_lane(0, k * w.road.lane_width_m, k, name=f"lane{k}")
    return lanemap


def recorded_inputs(info: RunInfo) -> HostInputs:
    """The mission of a recording (`/run/info`): a scenario's, rebuilt from its recorded text; a car's,
    from its recorded command line (`host.replay.car_run_inputs`)."""
    if not info.scenario_text or info.scenario_text.startswith("{"):
        return car_run_inputs(info)
    suffix = Path(info.scenario_source).suffix
    text = info.scenario_text
    data = tomllib.loads(text) if suffix == ".toml" else yaml.safe_load(text)
    return host_inputs(parse_scenario(data, f"{info.scenario_source} (as recorded)"))

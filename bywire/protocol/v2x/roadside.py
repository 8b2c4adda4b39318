"""A road side's phases placed at its stop lines: SPATEM + MAPEM -> `TrafficLightState` (ETSI TS 103 301).

A SPATEM says a signal group's phase, its intersection's MAPEM where that signal group's traffic stops.
`RoadsideView` keeps the stop lines of the maps it was given (per sending station, intersection and signal
group; at most `max_stop_lines`, the oldest forgotten first, so a flood of forged maps costs bounded memory)
and turns each SPATEM into the traffic lights it can place. A phase whose map has not been heard yet is
not placed (an RSU sends its MAPEM about once a second): `unplaced` counts them.
"""

from __future__ import annotations

from collections import OrderedDict

from .codec import SpeedLimit, TrafficLightState
from .dsrc import RoadMap, SignalPhases, StopLine


class RoadsideView:
    def __init__(self, max_stop_lines: int = 4096) -> None:
        self.max_stop_lines = max_stop_lines
        self._stop_lines: OrderedDict[tuple[int, int, int], StopLine] = OrderedDict()
        self.unplaced = 0

    def learn(self, road_map: RoadMap) -> tuple[SpeedLimit, ...]:
        """Remember the map's stop lines; its speed limits, as they are."""
        for m in road_map.intersections:
            for s in m.stop_lines:
                key = (road_map.station_id, m.intersection_id, s.signal_group)
                self._stop_lines[key] = s
                self._stop_lines.move_to_end(key)
        while len(self._stop_lines) > self.max_stop_lines:
            self._stop_lines.popitem(last=False)
        return road_map.speed_limits

    def place(self, phases: SignalPhases) -> list[TrafficLightState]:
        """The phases whose stop line is known, as traffic lights at their stop lines."""
        out = []
        for g in phases.groups:
            line = self._stop_lines.get((phases.station_id, g.intersection_id, g.signal_group))
            if line is None:
                self.unplaced += 1
                continue
            out.append(
                TrafficLightState(
                    phases.station_id, phases.generation_time_s, g.intersection_id, g.signal_group,
                    line.lat_deg, line.lon_deg, g.phase, g.time_to_change_s,
                )
            )  # fmt: skip
        return out

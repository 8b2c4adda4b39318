"""The Zone family (seed 000 Secs. 8, 10): the Zone state and its substates, one module each.

Sec. 8: "The navigation in unstructured environments and parking maneuvers is controlled by the state
Zone and its substates. These states control invocation of the navigation module described in Section
10." That module is `host.navigation` (hybrid A* on the obstacle map, Sec. 10), asked through
`behaviour.path_planning` on the zone's map (`zone_map`); where it finds no path, a **stand-in** takes
over (`navigator`): straight lines to a point `ZONE_SPOT_ALIGN_M` before the spot on its axis, into the
spot, back out along the axis, and straight on to the perimeter exit.

Speeds: the MDF's zone limit, at most `ZONE_SPEED_MAX_MPS`; into and out of the spot `SPOT_SPEED_MPS`.

- `family`: the Zone state itself (the navigator's life, leaving to Drive, the no-progress timer) and
  its substates in order;
- `approach`, `enter`, `park`, `leave`: ZoneApproach, ZoneEnter, ZonePark, ZoneLeave;
- `recovery`: ZoneRecovery;
- `navigator`: the navigation through the zone (`ZoneNavigator`, its `ZoneTarget`s: the planner's legs,
  the stand-in's where it has none) and what the states read of it: the zone speed and whether the
  front bumper is at the spot;
- `zone_map`: the zone's obstacle map and the parked pose in a spot.
"""

from .family import zone_family

__all__ = ["zone_family"]

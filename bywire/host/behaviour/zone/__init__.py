"""The Zone family (seed 000 Secs. 8, 10): the Zone state and its substates, one module each.

Sec. 8: "The navigation in unstructured environments and parking maneuvers is controlled by the state
Zone and its substates. These states control invocation of the navigation module described in Section
10." That module (hybrid A* on the obstacle map with Voronoi and RTR heuristics) comes later. Until then
the path inside a zone is a **simple stand-in** (`navigator`): straight lines from where we are to a
point `ZONE_SPOT_ALIGN_M` before the spot on its axis, into the spot to its checkpoint, back out along
the axis to that point, and from there straight to the perimeter exit and on along the exit edge. It
sees no obstacles but those on its lines (which stop it, as on a lane) and plans around none; a parking
lot with cars in the way will leave it to ZoneRecovery and then the GlobalRecovery.

Speeds: the MDF's zone limit, at most `ZONE_SPEED_MAX_MPS`; into and out of the spot `SPOT_SPEED_MPS`.

- `family`: the Zone state itself (the navigator's life, leaving to Drive, the no-progress timer) and
  its substates in order;
- `approach`, `enter`, `park`, `leave`: ZoneApproach, ZoneEnter, ZonePark, ZoneLeave;
- `recovery`: ZoneRecovery;
- `navigator`: the stand-in navigation (`ZoneNavigator`, its `ZoneTarget`s) and what the states read of
  it: the zone speed and whether the front bumper is at the spot.
"""

from .family import zone_family

__all__ = ["zone_family"]

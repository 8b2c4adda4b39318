"""Behaviour (seed 000 sections 8-9): traffic rules, the moving-traffic check, the hierarchical state machine.

- `rules`: named traffic-rule constants with their sources, and the moving-traffic check's parameter
  sets per situation (`MTC_SITUATIONS`).
- `mtc`: the moving-traffic check of Sec. 9 (eqs. 8-17), pure functions.
- `precedence`: four-way-stop precedence (`IntersectionPrecedence`, Sec. 9.3 case a, and the n x 10 s
  lesson of Sec. 12) and priority-road right of way (`right_of_way`, cases b and c).
- `hsm`: the statechart core (hierarchical states, guarded transitions evaluated top-down, no-progress
  timers driving each family's recovery); `situation`: its typed input (`Situation`) and output
  (`BehaviourCommand`); `context`, `route_view`, `lanes`, `manoeuvre`, `intersection_map`,
  `intersection_manager`: what the states read and compute.
- One package per state family (Fig. 11), one module per state, as AnnieWAY's planner has one file per
  state: `drive` (DriveOnLane, LaneChange, PassObstacle, DriveKTurn, DriveRecovery), `intersection`
  (Fig. 15 / Sec. 9.3), `zone` (a straight-line stand-in until the zone planner); each holds a `family`
  module (the composite state itself) and the helpers its states share. `recovery`: the top-level
  Replan, GlobalRecovery and MissionComplete.
- `behaviour`: `Behaviour.step(situation) -> BehaviourCommand`, the whole layer as one object.
- `diagram`: the hierarchy as one Mermaid or PNG diagram, generated from the code.
- `bench`: `bywire bench urban` timings of the above and of the lateral controller.
"""

"""Behaviour (seed 000 sections 8-9): traffic rules, the moving-traffic check, the hierarchical state machine.

- `rules`: named traffic-rule constants with their sources, and the moving-traffic check's parameter
  sets per situation (`MTC_SITUATIONS`).
- `mtc`: the moving-traffic check of Sec. 9 (eqs. 8-17), pure functions.
- `precedence`: four-way-stop precedence (`IntersectionPrecedence`, Sec. 9.3 case a, and the n x 10 s
  lesson of Sec. 12) and priority-road right of way (`right_of_way`, cases b and c).
- `bench`: `bywire bench urban` timings of the above and of the lateral controller.
"""

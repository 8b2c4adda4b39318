"""Top-level states off the normal flow (seed 000 Sec. 8): Replan, GlobalRecovery, MissionComplete.

Sec. 8: "In some situations it becomes necessary for the robot to replan its route, e.g., when the road
ahead is blocked. This is triggered by the state Replan, which reactivates the mission planning module.
[...] If all situation-dependent recovery handling fails, a global recovery state is invoked to navigate
back on track using the navigation module."

One module per state:

- `replan`: Replan;
- `global_recovery`: GlobalRecovery;
- `mission_complete`: MissionComplete, and `mission_done`, the guard by which the families end there;
- `common`: what they share with the families: `replan_from_here`, the one way back onto a route
  (Replan and GlobalRecovery), and `mark_blocked_at`, how a family reports a blockade before it
  replans.
"""

from .global_recovery import global_recovery_state
from .mission_complete import mission_complete_state
from .replan import replan_state

__all__ = ["global_recovery_state", "mission_complete_state", "replan_state"]

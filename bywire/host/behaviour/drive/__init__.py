"""The Drive family (seed 000 Sec. 8): the Drive state and its five substates, one module each.

Sec. 8: "The state Drive comprises all regular driving maneuvers on normal roads. It has several
substates that cover different situations, such as following the course of a lane (DriveOnLane),
making a k-turn (DriveKTurn), or changing the lane (LaneChange)." Passing a stopped or parked car is
ours to add (AnnieWAY's published code has it as `StDrivePassObstacle`), with its lane change out and
back. Every state has the same shape: a doc line, its entry/exit, its activity (what it plans each
cycle) and its transitions, the guards named for what they test and labelled with the rule.

- `family`: the Drive state itself (what holds in every substate) and its substates in order;
- `on_lane`: DriveOnLane, and its transitions out in their order of precedence;
- `lane_change`: LaneChange (Fig. 13 c);
- `pass_obstacle`: PassObstacle and its substates Wait, Out, By and Back (Fig. 13 d);
- `kturn`: DriveKTurn and its three legs;
- `recovery`: DriveRecovery;
- `common`: what several of them read: the still lead, a queue at an intersection (rules 1.7), the
  passing plan and the blockade ahead.
"""

from .family import drive_family

__all__ = ["drive_family"]

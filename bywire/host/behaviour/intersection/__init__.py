"""The Intersection family (seed 000 Sec. 9.3, Fig. 15): the Intersection state and its substates, one
module each.

Fig. 15 itself is not in our text of the paper; its transitions are the ones Sec. 9.3 describes, and
no others (each is quoted at its guard, in the module of the state it leaves):

    IntersectionApproach -> IntersectionQueue           "another traffic participant is perceived on the
                                                          same lane between AnnieWAY and the intersection"
    IntersectionQueue    -> IntersectionApproach        "until the other vehicle has passed the
                                                          intersection and the lane is free"
    IntersectionApproach -> IntersectionStop            (a) "if AnnieWAY is on a stop road"
    IntersectionApproach -> IntersectionPrioDriveInside (b) "on a priority road and no other vehicle has
                                                          the right-of-way"
    IntersectionApproach -> IntersectionPrioStop        (c) "on a priority road but needs to yield the
                                                          right-of-way to priority vehicles [...] before it
                                                          may turn left"
    IntersectionStop     -> IntersectionWait            "AnnieWAY stops at the stop line and changes into
                                                          the state IntersectionWait"
    IntersectionWait     -> IntersectionDriveInside     "As soon as these vehicles have passed the
                                                          intersection and the MTC turns out positive for
                                                          all visible priority vehicles"
    IntersectionPrioDriveInside -> IntersectionPrioStop "If a priority vehicle is perceived shortly after
                                                          driving inside the intersection (point of no
                                                          return has not been passed yet) and the MTC
                                                          turns out negative"
    IntersectionPrioStop -> IntersectionPrioDriveInside "waits until the MTC confirms that no danger comes
                                                          from priority vehicles anymore, and turns left"

Who may go is decided by the crossing's `IntersectionManager`: precedence at four-way stops
(`IntersectionPrecedence`: every vehicle that stopped before us goes first, in its order, each with its
own bounded turn - the n x 10 s of Sec. 12 done right) and the MTC for priority traffic (`right_of_way`
cases a-c), with the MTC's hysteresis once we set off.

- `family`: the Intersection state itself (the manager's life, leaving to Drive, the no-progress timer)
  and its substates in order;
- `approach`, `queue`, `stop`, `wait`, `drive_inside`: IntersectionApproach, IntersectionQueue,
  IntersectionStop, IntersectionWait, IntersectionDriveInside;
- `prio_drive_inside`, `prio_stop`: IntersectionPrioDriveInside and IntersectionPrioStop (priority road);
- `recovery`: IntersectionRecovery;
- `common`: what several of them read: the manager, the distance to the line, a vehicle before it, the
  MTC, and the go latch.
"""

from .family import intersection_family

__all__ = ["intersection_family"]

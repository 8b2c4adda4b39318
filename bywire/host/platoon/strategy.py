"""Platoon strategy of seed 003 (Team AnnieWAY, GCDC 2011), section V-D.

Every vehicle ahead (index i = 1 for the direct leader, i = 2 the one ahead of it, ...) is treated as a
single leader of the follow controller (eq. 1, `follow_qp.FollowQP`) with i times the safety distance
plus a slack: headway ``i * t_h`` and reserve ``i * r + (i - 1) * l``, i.e. the desired gap to vehicle
i is ``i * (r + t_h * v_i) + (i - 1) * l``. The smallest (most conservative) of the accelerations is
commanded; the vehicle it came from is the one the host is "locked" on (Fig. 5) and is reported.

The paper says the slack is added "to the safety distance multiplied by i - 1"; read as
``i * d + (i - 1) * l`` (no slack for the direct leader). Each farther vehicle thus asks for a gap l
larger than a rigid platoon would give it, so its demand is slightly more conservative and in steady
state the lock settles on the platoon's leader, the farthest vehicle (Fig. 5(a) "lock on the leader"),
not flickering between vehicles under noise; it moves to a nearer vehicle only when that one deviates
from its place by more than l (Fig. 5(b)), or at once when it brakes hard. Ties go to the nearest.

One `FollowQP` per index i, built on first use and kept (with the host-speed headway, t_h is in P).
An infeasible follow QP (a vehicle braking harder than our limits allow) yields ``a_min`` with
``feasible = False`` for that vehicle, which then binds: the most braking command.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

from .follow_qp import FollowParams, FollowQP, FollowResult, LeaderPrediction


@dataclass(frozen=True)
class PlatoonDecision:
    accel_cmd_mps2: float
    binding_index: int
    """1-based index of the vehicle ahead whose follow solution was taken (0: no vehicle ahead)."""
    per_leader: tuple[FollowResult, ...]

    @property
    def feasible(self) -> bool:
        return all(r.feasible for r in self.per_leader)


class PlatoonStrategy:
    def __init__(self, params: FollowParams, slack_m: float = 2.0) -> None:
        self.params = params
        self.slack_m = slack_m
        self._qps: list[FollowQP] = []

    def params_for(self, i: int) -> FollowParams:
        """Follow parameters toward vehicle i ahead: i times the safety distance plus (i - 1) slacks."""
        p = self.params
        return replace(p, headway_s=i * p.headway_s, reserve_m=i * p.reserve_m + (i - 1) * self.slack_m)

    def qp_for(self, i: int) -> FollowQP:
        while len(self._qps) < i:
            self._qps.append(FollowQP(self.params_for(len(self._qps) + 1)))
        return self._qps[i - 1]

    def step(self, speed_mps: float, leaders: Sequence[LeaderPrediction]) -> PlatoonDecision:
        """leaders[k] is vehicle i = k + 1 ahead; predictions relative to the host at t_0."""
        if not leaders:
            # No one ahead: nothing in V-D to follow; hold speed (the mission layer sets cruise speed).
            return PlatoonDecision(accel_cmd_mps2=0.0, binding_index=0, per_leader=())
        results: list[FollowResult] = []
        for k, leader in enumerate(leaders):
            i = k + 1
            results.append(self.qp_for(i).solve(speed_mps, leader))
        best = min(range(len(results)), key=lambda k: (results[k].accel_cmd_mps2, k))
        return PlatoonDecision(
            accel_cmd_mps2=results[best].accel_cmd_mps2,
            binding_index=best + 1,
            per_leader=tuple(results),
        )

"""The scenario's script as a mission module: speed profile, stop line, engage, scripted requests.

A stand-in until the mission planner of issue 5: it turns the scenario's `host` section (and the
host-side faults of its `faults` list: rearm pulses, STOP requests, a muted heartbeat) into one
`MissionCommand` per release, so every other module reads the mission from the store, as it will
once the planner exists.
"""

from __future__ import annotations

import math

from bywire.hil.scenario import Scenario, ramp_value, step_value
from bywire.host.modules.messages import MISSION, MissionCommand
from bywire.host.runtime.module import Module, ModuleContext

REARM_PULSE_S = 0.1  # long enough for the ECU to see a rising edge through a lost frame or two


class ScenarioMission(Module):
    def __init__(self, scenario: Scenario, t0_s: float) -> None:
        self.scenario = scenario
        self.t0_s = t0_s

    def _active(self, kind: str, t: float) -> bool:
        return any(f.kind == kind and f.active(t) for f in self.scenario.faults)

    def step(self, ctx: ModuleContext) -> None:
        sc = self.scenario
        t = ctx.now_s - self.t0_s
        ctx.publish(
            MISSION,
            MissionCommand(
                t_s=ctx.now_s,
                mode=sc.host_mode,
                v_des_mps=ramp_value(sc.speed_profile, t) if sc.speed_profile else 0.0,
                accel_mps2=step_value(sc.accel_profile, t) if sc.accel_profile else 0.0,
                steer_rad=step_value(sc.steer_profile, t) if sc.steer_profile else 0.0,
                steer=bool(sc.steer_profile),
                # An engage press lets go of ENGAGE for a moment: the mission asks anew.
                engage=t >= sc.engage_at_s and not self._active("engage_press", t),
                rearm=any(f.kind == "rearm" and f.at_s <= t < f.at_s + REARM_PULSE_S for f in sc.faults),
                stop=self._active("host_stop", t),
                heartbeat_mute=self._active("heartbeat_mute", t),
                stop_line_m=math.nan if sc.stop_line_m is None else sc.stop_line_m,
            ),
        )

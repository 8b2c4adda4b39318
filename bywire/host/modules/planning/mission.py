"""The driver's command script as a mission module: speed profile, stop line, engage, button pulses.

It turns a `host.command_script.CommandScript` (a car's `--commands` file or `--cruise` speed; a
scenario's `host:` section in the simulator) into one `MissionCommand` per release, so every other
module reads the mission from the store. The urban behaviour (seed 000 sections 8-9) plans on top
of it: the script's engage wish and buttons still come from here.
"""

from __future__ import annotations

from collections.abc import Callable

from bywire.host.command_script import CommandScript
from bywire.host.modules.messages import MISSION, MissionCommand
from bywire.host.runtime.module import Module, ModuleContext


class ScriptMission(Module):
    def __init__(self, script: CommandScript, t0_s: Callable[[], float]) -> None:
        self.script = script
        self.t0_s = t0_s  # read at each step: a module is built before a HIL run's start fixes t0

    def step(self, ctx: ModuleContext) -> None:
        c = self.script.at(ctx.now_s - self.t0_s())
        ctx.publish(
            MISSION,
            MissionCommand(
                t_s=ctx.now_s,
                mode=c.mode,
                v_des_mps=c.v_des_mps,
                accel_mps2=c.accel_mps2,
                steer_rad=c.steer_rad,
                steer=c.steer,
                engage=c.engage,
                rearm=c.rearm,
                stop=c.stop,
                stop_line_m=c.stop_line_m,
            ),
        )

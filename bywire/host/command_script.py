"""The spine's command source: what the driver commands over time, as a script.

Seed 000 section 11.2's longitudinal controller drives at the commanded speed (mode `drive`, a speed profile
and an optional stop line); mode `script` passes a commanded acceleration through to the ECU (a test
drive on a closed track). Besides speeds, a script holds when the driver's engage wish starts and the
driver's button pulses: re-arm requests, controlled STOP requests, and moments in which the engage wish
is let go and asked anew.

On a car the script is a small YAML file (`bywire host run CONFIG --commands FILE`) or a constant cruise
speed (`--cruise V`); in the simulator it is a scenario's `host:` section. Times are seconds from the
host's start, speeds m/s, accelerations m/s^2, distances m along the path from the start::

    mode: drive                 # drive | script
    engage_at_s: 1.0            # the engage wish from here on (omitted: never)
    speed_mps: [[0, 0], [10, 8], [60, 8]]   # (t_s, v) ramps; a number is a constant speed
    stop_line_m: 120            # optional: stop at this distance
    rearm_at_s: [30.0]          # re-arm pulses
    stop: [{at_s: 40, duration_s: 5}]       # controlled STOP requests (duration 0: to the end)
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from bywire.profiles import Profile, ramp_value, step_value
from bywire.schema import Reader, SchemaError

MODES = ("drive", "script")
REARM_PULSE_S = 0.1  # long enough for the ECU to see a rising edge through a lost frame or two


class CommandScriptError(SchemaError):
    """A command script that cannot be driven, with the file and the path of the bad field."""


class _Reader(Reader):
    error_type = CommandScriptError


@dataclass(frozen=True)
class Window:
    """From `at_s` for `duration_s` (0: to the end of the run)."""

    at_s: float
    duration_s: float = 0.0

    def active(self, t_s: float) -> bool:
        return self.at_s <= t_s and (self.duration_s == 0.0 or t_s < self.at_s + self.duration_s)


@dataclass(frozen=True)
class Command:
    """The script's command at one instant."""

    mode: str
    v_des_mps: float
    accel_mps2: float
    steer_rad: float
    steer: bool
    engage: bool
    rearm: bool
    stop: bool
    stop_line_m: float  # nan: none


@dataclass(frozen=True)
class CommandScript:
    mode: str = "drive"
    speed_profile: Profile = ()
    accel_profile: Profile = ()
    steer_profile: Profile = ()
    engage_at_s: float = math.inf
    stop_line_m: float | None = None
    rearm_at_s: tuple[float, ...] = ()
    stop: tuple[Window, ...] = ()
    engage_release: tuple[Window, ...] = ()  # the engage wish let go for a moment, then asked anew
    source: str = "<commands>"

    def at(self, t_s: float) -> Command:
        return Command(
            mode=self.mode,
            v_des_mps=ramp_value(self.speed_profile, t_s) if self.speed_profile else 0.0,
            accel_mps2=step_value(self.accel_profile, t_s) if self.accel_profile else 0.0,
            steer_rad=step_value(self.steer_profile, t_s) if self.steer_profile else 0.0,
            steer=bool(self.steer_profile),
            engage=t_s >= self.engage_at_s and not any(w.active(t_s) for w in self.engage_release),
            rearm=any(at <= t_s < at + REARM_PULSE_S for at in self.rearm_at_s),
            stop=any(w.active(t_s) for w in self.stop),
            stop_line_m=math.nan if self.stop_line_m is None else self.stop_line_m,
        )


def cruise(speed_mps: float, engage_at_s: float = 0.0) -> CommandScript:
    """Drive at a constant speed, asking to engage from `engage_at_s` (the ECU engages only when its
    driver has armed it)."""
    if not math.isfinite(speed_mps) or not 0.0 <= speed_mps <= 60.0:
        raise ValueError(f"cruise speed must be within 0..60 m/s, got {speed_mps}")
    return CommandScript(
        speed_profile=((0.0, speed_mps),), engage_at_s=engage_at_s, source=f"cruise {speed_mps}"
    )


def _windows(r: _Reader, key: str) -> tuple[Window, ...]:
    raw = r.raw(key, [])
    if not isinstance(raw, list):
        raise r.error(key, f"expected a list of {{at_s, duration_s}}, got {raw!r}")
    out = []
    for i, item in enumerate(raw):
        w = _Reader(item, r.source, f"{key}[{i}]")
        out.append(Window(w.number("at_s", lo=0.0), w.number("duration_s", 0.0, lo=0.0)))
        w.finish()
    return tuple(out)


def parse_command_script(data: Any, source: str) -> CommandScript:
    r = _Reader(data, source, "")
    rearm = r.raw("rearm_at_s", [])
    if not isinstance(rearm, list) or not all(
        isinstance(v, int | float) and not isinstance(v, bool) and v >= 0 for v in rearm
    ):
        raise r.error("rearm_at_s", f"expected a list of times >= 0 s, got {rearm!r}")
    engage_at_s = r.opt_number("engage_at_s", lo=0.0)
    script = CommandScript(
        mode=r.string("mode", "drive", MODES),
        speed_profile=r.profile("speed_mps"),
        accel_profile=r.profile("accel_mps2"),
        steer_profile=r.profile("steer_rad"),
        engage_at_s=math.inf if engage_at_s is None else engage_at_s,
        stop_line_m=r.opt_number("stop_line_m", lo=0.0),
        rearm_at_s=tuple(float(v) for v in rearm),
        stop=_windows(r, "stop"),
        engage_release=_windows(r, "engage_release"),
        source=source,
    )
    r.finish()
    return script


def load_command_script(path: str | Path) -> CommandScript:
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise CommandScriptError(str(p), "", f"cannot read the command script: {exc}") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise CommandScriptError(str(p), "", f"not valid YAML: {exc}") from None
    return parse_command_script(data, str(p))

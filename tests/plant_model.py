"""A small pure-Python point-mass car with the FMU plant's equations, for the ECU core's tests.

Same equations and parameters as the FMU plant (vehicle_models/): mass 1650 kg; drive force
throttle/100 * min(5200 N, 103 kW / max(v, 1 m/s)) behind a 0.25 s first-order lag; brake force
140 N/bar * p with a 0.10 s pressure lag, 0..200 bar; drag 0.5 * 1.2 * 0.70 * v^2; rolling
resistance m g c_rr with c_rr = 0.011; grade force m g sin(atan(grade)); steering with a 0.1 s lag,
0.7 rad/s rate limit and +-30 deg. The lags are discretised exactly (x += (u - x)(1 - e^(-dt/tau))).

Brakes and rolling resistance are Coulomb friction: they oppose motion and, at standstill, hold the
car up to their magnitude, so a held car on a slope stays put and a released one rolls back. The
car may roll backwards (v < 0); like the wheel-speed sensors, `speed_mps` reports |v|, while
`accel_mps2` (the INS) is signed in the vehicle frame. `gear` (+1 drive, -1 reverse) sets the drive
force's direction, as the FMU's `gear` input; `GearSelector` is the gateway's selector of
hil/plant.py (shift only at standstill with the brake applied, after SHIFT_DELAY_S).

`CoreLoop` closes the ECU core (`bywire.ecu.core.core_step`) around the model for the tests.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from bywire.ecu.calibration import Calibration
from bywire.ecu.core import ActuatorCommand, EcuInputs, core_step, initial_core_state
from bywire.hil.plant import SHIFT_BRAKE_MIN_BAR, SHIFT_DELAY_S, SHIFT_STANDSTILL_SPEED_MPS
from bywire.protocol.ecu_types import EstopMode, Gear, RequestFlags

G_MPS2 = 9.81


@dataclass
class PlantParams:
    mass_kg: float = 1650.0
    drive_force_max_n: float = 5200.0
    drive_power_max_w: float = 103_000.0
    drive_lag_s: float = 0.25
    brake_gain_n_per_bar: float = 140.0
    brake_lag_s: float = 0.10
    brake_bar_max: float = 200.0
    rho_kgpm3: float = 1.2
    cda_m2: float = 0.70
    c_rr: float = 0.011
    steer_lag_s: float = 0.1
    steer_rate_max_radps: float = 0.7
    steer_max_rad: float = math.radians(30.0)
    park_brake_force_n: float = 8000.0


class PointMassPlant:
    """Longitudinal point mass plus a lagged, rate-limited steering actuator."""

    def __init__(self, speed_mps: float = 0.0, grade: float = 0.0, params: PlantParams | None = None) -> None:
        self.p = params or PlantParams()
        self.v_mps = speed_mps
        self.grade = grade  # rise over run, + uphill
        self.drive_force_n = 0.0  # lagged state
        self.brake_bar = 0.0  # lagged state
        self.steer_rad = 0.0
        self.accel_mps2 = 0.0  # dv/dt over the last step (the INS's "gravity removed" acceleration)
        self.x_m = 0.0
        self.gear = Gear.DRIVE  # engaged; the drive force pushes backwards in REVERSE

    @property
    def speed_mps(self) -> float:
        return abs(self.v_mps)

    def _drive_force_max_n(self) -> float:
        return min(self.p.drive_force_max_n, self.p.drive_power_max_w / max(abs(self.v_mps), 1.0))

    def step(
        self,
        dt_s: float,
        throttle_pct: float,
        brake_bar: float,
        steer_angle_rad: float = 0.0,
        *,
        ignition: bool = True,
        park_brake: bool = False,
    ) -> None:
        p = self.p
        thr = min(max(throttle_pct, 0.0), 100.0) if ignition else 0.0
        brk = min(max(brake_bar, 0.0), p.brake_bar_max)
        k_drive = 1.0 - math.exp(-dt_s / p.drive_lag_s)
        k_brake = 1.0 - math.exp(-dt_s / p.brake_lag_s)
        sign = -1.0 if self.gear == Gear.REVERSE else 1.0
        self.drive_force_n += (sign * thr / 100.0 * self._drive_force_max_n() - self.drive_force_n) * k_drive
        self.brake_bar += (brk - self.brake_bar) * k_brake

        theta = math.atan(self.grade)
        m = p.mass_kg
        v = self.v_mps
        # Forces along the road, + forward; friction-like terms handled separately.
        f_ext = self.drive_force_n - 0.5 * p.rho_kgpm3 * p.cda_m2 * v * abs(v) - m * G_MPS2 * math.sin(theta)
        f_fric = p.brake_gain_n_per_bar * self.brake_bar + m * G_MPS2 * math.cos(theta) * p.c_rr
        if park_brake:
            f_fric += p.park_brake_force_n
        if v == 0.0:
            # Static friction holds the car unless the other forces overcome it.
            a = 0.0 if abs(f_ext) <= f_fric else (f_ext - math.copysign(f_fric, f_ext)) / m
            v_new = v + a * dt_s
        else:
            a = (f_ext - math.copysign(f_fric, v)) / m
            v_new = v + a * dt_s
            if v_new * v < 0.0:  # friction cannot reverse the motion: stop at zero this step
                v_new = 0.0
        self.accel_mps2 = (v_new - v) / dt_s
        self.x_m += 0.5 * (v + v_new) * dt_s
        self.v_mps = v_new

        k_steer = 1.0 - math.exp(-dt_s / p.steer_lag_s)
        lim = p.steer_max_rad
        target = min(max(steer_angle_rad, -lim), lim)
        rate = (target - self.steer_rad) * k_steer / dt_s
        rate = min(max(rate, -p.steer_rate_max_radps), p.steer_rate_max_radps)
        self.steer_rad += rate * dt_s


class GearSelector:
    """The gateway's selector (hil/plant.py `Plant._shift`): a requested gear is engaged SHIFT_DELAY_S
    after the request, if the car stays at standstill with the brake applied all along; `stuck`
    makes it ignore every request (a broken selector)."""

    def __init__(self, stuck: bool = False) -> None:
        self.stuck = stuck
        self.shift_to: Gear | None = None
        self.done_s = math.inf
        self.refused = 0

    def step(self, now_s: float, plant: PointMassPlant, requested: Gear, brake_bar: float) -> None:
        held = abs(plant.v_mps) < SHIFT_STANDSTILL_SPEED_MPS and brake_bar >= SHIFT_BRAKE_MIN_BAR
        if self.stuck or requested == plant.gear:
            self.shift_to, self.done_s = None, math.inf
            return
        if self.shift_to != requested or not held:
            if not held:
                self.refused += 1
            self.shift_to, self.done_s = (requested, now_s + SHIFT_DELAY_S) if held else (None, math.inf)
        elif now_s >= self.done_s:
            plant.gear, self.shift_to, self.done_s = requested, None, math.inf


# --- the ECU core in closed loop with the model ----------------------------------------------------


def healthy_inputs(**changes: Any) -> EcuInputs:
    """ECU inputs with every engage precondition met and ENGAGE | STEER requested; `changes`
    override fields."""
    fields: dict[str, Any] = {
        "estop_mode": EstopMode.RUN,
        "estop_fresh": True,
        "host_alive": True,
        "request_accel_mps2": 0.0,
        "request_steer_angle_rad": 0.0,
        "request_flags": RequestFlags.ENGAGE | RequestFlags.STEER,
        "request_fresh": True,
        "vehicle_fresh": True,
        "vehicle_corrupt": False,
        "calibration_valid": True,
        "overrun_streak": 0,
        "driver_brake_pressed": False,
        "driver_throttle_pct": 0.0,
        "driver_steer_torque_nm": 0.0,
        "speed_mps": 0.0,
        "accel_meas_mps2": 0.0,
        "steer_angle_meas_rad": 0.0,
        "unlatch": False,
    }
    fields.update(changes)
    return EcuInputs(**fields)


class CoreLoop:
    """`core_step` closed around a `PointMassPlant` on a simulated time base.

    Each `step` builds the inputs from the plant (speed, measured acceleration, steering angle)
    plus the caller's overrides; while vehicle data is not fresh the last fresh measurements are
    repeated, as an I/O layer would. The plant gets the ECU's commands when `engage` is set and
    released pedals otherwise (nobody drives)."""

    def __init__(
        self,
        cal: Calibration,
        *,
        speed_mps: float = 0.0,
        grade: float = 0.0,
        dt_s: float = 0.001,
        plant: PointMassPlant | None = None,
        selector: GearSelector | None = None,
    ) -> None:
        self.cal = cal
        self.selector = selector or GearSelector()
        self.dt_s = dt_s
        self.plant = plant or PointMassPlant(speed_mps=speed_mps, grade=grade)
        self.t_s = 0.0
        self.state = initial_core_state(self.t_s)
        self.cmd: ActuatorCommand | None = None
        self.last_inputs: EcuInputs | None = None
        self._meas = self._measure()

    def _measure(self) -> tuple[float, float, float, Gear]:
        return (self.plant.speed_mps, self.plant.accel_mps2, self.plant.steer_rad, self.plant.gear)

    def inputs(self, **changes: Any) -> EcuInputs:
        if changes.get("vehicle_fresh", True):
            self._meas = self._measure()
        speed, accel, steer, gear = self._meas
        base: dict[str, Any] = {
            "speed_mps": speed,
            "accel_meas_mps2": accel,
            "steer_angle_meas_rad": steer,
            "gear_engaged": gear,
            "wheel_speed_max_mps": speed,  # a point mass: every wheel turns at the car's speed
        }
        base.update(changes)
        return healthy_inputs(**base)

    def step(self, **changes: Any) -> ActuatorCommand:
        self.t_s += self.dt_s
        inp = self.inputs(**changes)
        self.state, cmd = core_step(self.state, inp, self.t_s, self.cal)
        if cmd.engage:
            self.selector.step(self.t_s, self.plant, cmd.gear_request, cmd.brake_bar)
            self.plant.step(
                self.dt_s,
                cmd.throttle_pct,
                cmd.brake_bar,
                cmd.steer_angle_rad,
                ignition=cmd.ignition,
                park_brake=cmd.park_brake,
            )
        else:
            self.plant.step(self.dt_s, 0.0, 0.0, self.plant.steer_rad)
        self.cmd = cmd
        self.last_inputs = inp
        return cmd

    def run(self, duration_s: float, **changes: Any) -> ActuatorCommand:
        n = max(1, round(duration_s / self.dt_s))
        cmd = self.step(**changes)
        for _ in range(n - 1):
            cmd = self.step(**changes)
        return cmd

    def run_until(self, pred: Callable[[ActuatorCommand], bool], timeout_s: float, **changes: Any) -> float:
        """Step until pred(cmd) holds; return the time it took (inf on timeout)."""
        t0 = self.t_s
        while self.t_s - t0 < timeout_s:
            if pred(self.step(**changes)):
                return self.t_s - t0
        return math.inf

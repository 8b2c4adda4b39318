"""SIL's ECU stepping: quiet cycles run as the controller's recurrence alone (DESIGN section 1).

In lockstep the ECU's cycle runs every simulated millisecond, and in most of them nothing reaches
the ECU (no frame on vehicle CAN or the host link), nothing leaves it (no DBW_Command, status TPDO,
heartbeat or EMCY is due), its inputs object is reused, and its safety state machine stands still
(`safety_transition` returns its state unchanged). Such a *quiet* cycle changes only the core's
acceleration loop, its steering command and its speed estimate; everything else the full cycle does
(drain two empty queues, judge the same inputs again, build the state and command objects nobody
reads before the next full cycle) leaves the ECU as it was.

A quiet run (`QuietRun`) therefore runs a quiet cycle as the firmware's own pure functions on
that part alone (`controller_cycle`, `steer_step` / `clamp_steer`, with the arguments the core's
branch for the state gives them: `core._step_engaged`, `_step_stop`, `_step_passive`), and its
last cycle through the firmware's `core_step` itself, from the state the quiet cycles reached: the
ECU's `core` and `last_command` after a quiet run are the ones the full cycles would have left, bit
for bit. A cycle is quiet only while every condition that makes it so holds: in the core
(`quiet_mode`: inputs reused, the safety state standing still, driving without a shift, or a stop
continued before its deadline, or hands off) and around it (`QuietCycleStepper`: no event pending,
no frame queued, no transmission and no node timer due, no loop stall). Anything else is a full
`EcuApp.step`, after the pending quiet run is settled.

Deviation from running the firmware unchanged: none in what the ECU computes or sends; it is the
same code on the same values. What is skipped is proven idle by those checks, and
tests/hil/test_sil_quiet_ecu.py holds the two paths equal: a quiet run against `core_step` on
random states and inputs, and cycle by cycle on whole scenarios (every state, command, trace and
summary). `run_sil(..., quiet_ecu=False)` runs
every cycle in full, the reference.

Only for SIL: the firmware image runs every cycle in full (a real ECU's cycle is paced by the
clock, not by its cost), and this module is not in it.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sized

from bywire.ecu.accel_controller import ControllerState, controller_cycle, steer_step, step_dt_s
from bywire.ecu.app import LOOP_STALL_MAX_GAP_S, EcuApp
from bywire.ecu.calibration import Calibration
from bywire.ecu.core import CoreState, clamp_steer, core_step
from bywire.ecu.gear import reverse_accel_limit_mps2
from bywire.ecu.safety import STOP_STATES, EcuInputs, safety_transition
from bywire.hil.sil_bus import SimVirtualBus
from bywire.protocol.ecu_types import EcuState, Gear

_ENGAGED = EcuState.ENGAGED
_REVERSE = Gear.REVERSE
_INF = math.inf
# What a quiet run continues: driving (ENGAGED), a stop (PAUSED, SAFE_STOP, DISABLED), or hands off.
DRIVE, STOP, PASSIVE = "drive", "stop", "passive"


def quiet_mode(st: CoreState, inputs: EcuInputs, cal: Calibration) -> str | None:
    """What the next cycles continue if they get `inputs` again (the very object `st` was computed
    from) and nothing else happens: DRIVE, STOP or PASSIVE; None if such a cycle may change more
    than `QuietRun` follows. They are quiet until `quiet_deadline_s(st)` at the latest."""
    verdict = st.verdict
    if verdict is None or verdict.inputs is not inputs or verdict.cal is not cal:
        return None
    state = st.safety.state
    if state is _ENGAGED and not (verdict.wanted_gear == st.gear_request == inputs.gear_engaged):
        return None  # shifting (otherwise no gear confirmation or shift hold is pending: the core
        # keeps `gear_wait_s` and `shift_hold_s` at inf while the gears agree, and in every other state)
    # The safety state machine stands still on these inputs: the core's branch is this state's, a
    # stop is continued (not entered), the latched faults stay.
    if safety_transition(st.safety, inputs, verdict.active, cal) is not st.safety:
        return None
    if state is _ENGAGED:
        return DRIVE
    return STOP if state in STOP_STATES else PASSIVE


def quiet_deadline_s(st: CoreState) -> float:
    """A stop not yet holding latches its hold at its deadline: that cycle is not quiet."""
    if st.safety.state in STOP_STATES and not st.holding:
        return st.stop_deadline_s
    return _INF


@dataclasses.dataclass(slots=True)
class QuietRun:
    """Quiet cycles from `core0` (the state a full cycle left) on the same inputs: `advance(t)` is one
    cycle at t, `state()` the CoreState they reached, for `core_step` to take the next cycle from.

    What changes: the controller, the steering command and the speed estimate (DRIVE, STOP); in a
    hands-off state nothing `core_step` reads again (the controller restarts from the measurement
    every cycle, the steering and speed estimate fall back to the same values), so PASSIVE advances
    nothing and `state()` is `core0`."""

    mode: str
    core0: CoreState
    inputs: EcuInputs
    cal: Calibration
    ctl: ControllerState
    steer_rad: float
    steer_enable: bool
    v_est_mps: float
    trusted_t_s: float
    a_req_mps2: float = 0.0  # the controller's request: the host's (capped in reverse) or the stop's
    accel_meas_mps2: float = 0.0  # the measurement the controller is given
    advanced: bool = False

    @classmethod
    def start(cls, mode: str, core0: CoreState, inputs: EcuInputs, cal: Calibration) -> QuietRun:
        run = cls(
            mode,
            core0,
            inputs,
            cal,
            core0.controller,
            core0.steer_angle_rad,
            core0.steer_enable,
            core0.speed_est_mps,
            core0.speed_trusted_t_s,
        )
        verdict = core0.verdict
        assert verdict is not None
        if mode is DRIVE:
            a_req = inputs.request_accel_mps2
            if inputs.gear_engaged == _REVERSE:
                a_lim = reverse_accel_limit_mps2(inputs.speed_mps)
                if a_req > a_lim:
                    a_req = a_lim
            run.a_req_mps2 = a_req
            run.accel_meas_mps2 = verdict.accel_along_mps2
        elif mode is STOP:
            # What `core._step_stop` asks for in a stop it continues: the largest of this cycle's
            # deceleration and the stop's so far, which is the stop's so far (the cycle that left
            # core0 took the same largest on the same inputs and in the same state).
            run.a_req_mps2 = -core0.stop_decel_mps2
            run.accel_meas_mps2 = verdict.accel_along_mps2 if verdict.usable else 0.0
        return run

    def advance(self, now_s: float) -> None:
        """One quiet cycle at `now_s`."""
        mode = self.mode
        if mode is PASSIVE:
            return
        inputs = self.inputs
        verdict = self.core0.verdict
        assert verdict is not None
        cal = self.cal
        ctl_prev = self.ctl
        ok = verdict.usable
        v_prev = self.v_est_mps
        if ok:
            self.v_est_mps, self.trusted_t_s = inputs.speed_mps, now_s
        if mode is DRIVE:
            self.ctl = controller_cycle(
                ctl_prev,
                now_s,
                self.a_req_mps2,
                self.accel_meas_mps2,
                inputs.speed_mps,
                True,  # closed_loop
                True,  # throttle_allowed
                False,  # hold
                cal,
            )[0]
            if verdict.steer_requested:
                dt = step_dt_s(ctl_prev.t_s, now_s)
                self.steer_rad = steer_step(self.steer_rad, inputs.request_steer_angle_rad, dt, cal)
            else:
                self.steer_rad = clamp_steer(inputs.steer_angle_meas_rad, self.steer_rad, cal)
        else:
            holding = self.core0.holding
            out = controller_cycle(
                ctl_prev,
                now_s,
                self.a_req_mps2,
                self.accel_meas_mps2,
                inputs.speed_mps if ok else v_prev,
                ok,  # closed_loop
                False,  # throttle_allowed
                holding,  # hold
                cal,
            )
            self.ctl = out[0]
            if not ok and not holding:  # a blind stop integrates its speed estimate (target: out[4])
                v = v_prev + out[4] * step_dt_s(ctl_prev.t_s, now_s)
                self.v_est_mps = 0.0 if v < 0.0 else v
            # Steering stays as the stop found it while enabled; a DISABLE's hold (the ignition off)
            # releases it, but the hold is latched by a cycle that is not quiet, which released it.
            if not self.steer_enable:
                self.steer_rad = clamp_steer(inputs.steer_angle_meas_rad, self.steer_rad, cal)
        self.advanced = True

    def state(self) -> CoreState:
        if not self.advanced:
            return self.core0
        return dataclasses.replace(
            self.core0,
            controller=self.ctl,
            steer_angle_rad=self.steer_rad,
            steer_enable=self.steer_enable,
            speed_est_mps=self.v_est_mps,
            speed_trusted_t_s=self.trusted_t_s,
        )


class QuietCycleStepper:
    """Steps one `EcuApp` on SIL's simulated clock, quiet cycles on the cheap path.

    Call `step(t)` where SIL would call `ecu.step(t)`, and `settle()` before reading the ECU
    (`core`, `last_command`) between steps or at the end of a run."""

    def __init__(self, ecu: EcuApp, enabled: bool = True) -> None:
        self.ecu = ecu
        vehicle_bus, link_bus = ecu.vehicle_bus, ecu.node._bus
        # The checks read the ECU's and its CANopen node's bookkeeping and the frames queued for it;
        # on a bus other than SIL's (whose queue they inspect) every cycle runs in full.
        self.enabled = (
            enabled and isinstance(vehicle_bus, SimVirtualBus) and isinstance(link_bus, SimVirtualBus)
        )
        # The frames waiting for the ECU's two receivers (each bus's queue, as `SimVirtualBus.recv` reads it).
        self._queued: tuple[Sized, ...] = (
            (vehicle_bus.queue.queue, link_bus.queue.queue) if self.enabled else ()  # type: ignore[attr-defined]
        )
        self.quiet_cycles = 0
        self.full_cycles = 0
        self.run: QuietRun | None = None  # the pending quiet run; `_held_t` its last cycle, not settled
        self._held_t = 0.0
        self._mode: str | None = None  # what a run that may start now continues (`quiet_mode`)
        self._run_until = -_INF  # and it ends before this time

    def step(self, now_s: float) -> None:
        """One ECU cycle at `now_s` (the simulated clock already there)."""
        ecu = self.ecu
        run = self.run
        if self.enabled and (run is not None or self._run_may_start(now_s)) and self._quiet_now(now_s):
            started = ecu.clock.now()
            last = ecu._last_cycle_s
            if last is not None and started - last <= LOOP_STALL_MAX_GAP_S:
                # What `EcuApp.step` and its poll of an empty queue record of a cycle.
                ecu._last_cycle_s = started
                gap = started - last
                if gap > ecu.max_cycle_gap_s:
                    ecu.max_cycle_gap_s = gap
                ecu.node._rx_now_s = now_s
                if run is None:
                    ecu_inputs = ecu._last_inputs
                    assert ecu_inputs is not None and self._mode is not None
                    self.run = QuietRun.start(self._mode, ecu.core, ecu_inputs, ecu._core_cal)
                else:
                    run.advance(self._held_t)
                self._held_t = now_s
                self.quiet_cycles += 1
                return
        self.settle()
        self.full_cycles += 1
        ecu.step(now_s)

    def settle(self) -> None:
        """Run the pending quiet run's last cycle through `core_step`, leaving the ECU's `core` and
        `last_command` as the full cycles would have."""
        run = self.run
        if run is None:
            return
        self.run = None
        ecu = self.ecu
        ecu.core, cmd = core_step(run.state(), run.inputs, self._held_t, run.cal)
        ecu.last_command = cmd
        ecu.guard.note_cycle(cmd.steer_enable)

    def _quiet_now(self, now_s: float) -> bool:
        """This millisecond's part of the checks: nothing queued, before the run's first deadline."""
        vehicle, link = self._queued
        return now_s < self._run_until and not vehicle and not link

    def _run_may_start(self, now_s: float) -> bool:
        """Whether a quiet run may begin at `now_s` (after a full cycle): the conditions that hold for
        the whole run, and the first time one of them may stop holding (`_run_until`)."""
        ecu = self.ecu
        inputs = ecu._last_inputs
        self._run_until = -_INF
        self._mode = None
        if (
            inputs is None
            # the inputs are reused: what `EcuApp._cycle` compares, with no event pending at all (an
            # event is judged once: the cycle after it recomputes the inputs without it)
            or ecu._unlatch_pending
            or ecu._stall_pending
            or ecu._internal_pending
            or ecu._guard_pending
            or inputs.unlatch
            or inputs.loop_stall
            or inputs.internal_error
            or inputs.tx_guard_trip
            or ecu.stats.overrun_streak != inputs.overrun_streak
            or ecu.node._rx_frames != ecu.node._quiet_rx_frames  # the node's tick has work
        ):
            return False
        st = ecu.core
        mode = quiet_mode(st, inputs, ecu._core_cal)
        # The faults reported stay those reported (active and latched: the same verdict and state).
        if mode is None or int(st.verdict.faults) | int(st.safety.latched) != ecu._reported_faults:  # type: ignore[union-attr]
            return False
        node = ecu.node
        # Not quiet from: the inputs' expiry (reused while now <= valid_until), the next command and
        # status, the node's next timer, a stop's deadline.
        self._run_until = min(
            math.nextafter(ecu._inputs_valid_until_s, _INF),
            ecu._next_command_s,
            ecu._next_status_s,
            node._quiet_until_s,
            quiet_deadline_s(st),
        )
        self._mode = mode
        return now_s < self._run_until

"""SIL's ECU stepping: quiet cycles run as the controller's recurrence alone (DESIGN section 1).

In lockstep the ECU's cycle runs every simulated millisecond, and in most of them nothing reaches
the ECU (no frame on vehicle CAN or the host link), nothing leaves it (no DBW_Command, status TPDO,
heartbeat or EMCY is due), its inputs object is reused, and its safety state machine stands still
(`safety_transition` returns its state unchanged). Such a *quiet* cycle changes only the core's
acceleration loop, its steering command and its speed estimate; everything else the full cycle does
(drain two empty queues, judge the same inputs again, build the state and command objects nobody
reads before the next full cycle) leaves the ECU as it was.

`QuietCycleStepper` therefore runs a quiet cycle as the firmware's own pure functions on that part
alone (`controller_cycle`, `steer_step` / `clamp_steer`, with the arguments `core._step_engaged`
gives them), and the last cycle of a quiet run through the firmware's `core_step` itself, from the
state the quiet cycles reached: the ECU's `core` and `last_command` after a quiet run are the ones
the full cycles would have left, bit for bit. A cycle is quiet only while every condition that
makes it so is checked (`_run_may_start`, and per millisecond `step`): ENGAGED, driving (not
shifting), inputs reused, no frame queued, no transmission and no node timer due, no loop stall.
Anything else is a full `EcuApp.step`, after the pending quiet cycle is settled.

Deviation from running the firmware unchanged: none in what the ECU computes or sends; it is the
same code on the same values. What is skipped is proven idle by those checks, and
tests/hil/test_sil_quiet_ecu.py holds the two paths equal: cycle by cycle on recorded and random
states, and on whole scenarios (every trace, every summary). `run_sil(..., quiet_ecu=False)` runs
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
from bywire.ecu.core import CoreState, clamp_steer, core_step
from bywire.ecu.gear import reverse_accel_limit_mps2
from bywire.ecu.safety import EcuInputs, safety_transition
from bywire.hil.sil_bus import SimVirtualBus
from bywire.protocol.ecu_types import EcuState, Gear

_ENGAGED = EcuState.ENGAGED
_REVERSE = Gear.REVERSE
_INF = math.inf


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
        self._run = False  # a quiet run is pending: `_held_t` is its last cycle, not yet settled
        self._run_until = -_INF  # the run ends before this time (the first that may not be quiet)
        self._held_t = 0.0
        self._core0: CoreState | None = None  # the state the run began from
        self._inputs: EcuInputs | None = None
        self._ctl: ControllerState | None = None
        self._steer = 0.0
        self._v_est = 0.0
        self._trusted_t = 0.0
        self._advanced = False  # some cycle of the run has been advanced (the state is not core0)
        self._a_req = 0.0
        self._accel_along = 0.0

    # -- stepping ------------------------------------------------------------------------------------

    def step(self, now_s: float) -> None:
        """One ECU cycle at `now_s` (the simulated clock already there)."""
        ecu = self.ecu
        if self.enabled and (self._run or self._run_may_start(now_s)) and self._quiet_now(now_s):
            started = ecu.clock.now()
            last = ecu._last_cycle_s
            if last is not None and started - last <= LOOP_STALL_MAX_GAP_S:
                ecu._last_cycle_s = started
                gap = started - last
                if gap > ecu.max_cycle_gap_s:
                    ecu.max_cycle_gap_s = gap
                ecu.node._rx_now_s = now_s  # what its poll of an empty queue sets
                if self._run:
                    self._advance(self._held_t)
                else:
                    self._run = True
                self._held_t = now_s
                self.quiet_cycles += 1
                return
        self.settle()
        self.full_cycles += 1
        ecu.step(now_s)

    def settle(self) -> None:
        """Run the pending quiet run's last cycle through `core_step`, leaving the ECU's `core` and
        `last_command` as the full cycles would have."""
        if not self._run:
            return
        self._run = False
        ecu = self.ecu
        core0 = self._core0
        inputs = self._inputs
        assert core0 is not None and inputs is not None
        st = core0
        if self._advanced:
            assert self._ctl is not None
            st = dataclasses.replace(
                core0,
                controller=self._ctl,
                steer_angle_rad=self._steer,
                speed_est_mps=self._v_est,
                speed_trusted_t_s=self._trusted_t,
            )
        ecu.core, cmd = core_step(st, inputs, self._held_t, ecu._core_cal)
        ecu.last_command = cmd
        ecu.guard.note_cycle(cmd.steer_enable)
        ecu._unlatch_pending = ecu._stall_pending = ecu._internal_pending = ecu._guard_pending = False

    # -- what makes a cycle quiet --------------------------------------------------------------------

    def _quiet_now(self, now_s: float) -> bool:
        """This millisecond's part of the checks: nothing queued, before the run's first deadline."""
        vehicle, link = self._queued
        return now_s < self._run_until and not vehicle and not link

    def _run_may_start(self, now_s: float) -> bool:
        """Whether a quiet run may begin at `now_s` (after a full cycle): the conditions that hold for
        the whole run, and the first time one of them may stop holding (`_run_until`)."""
        ecu = self.ecu
        inputs = ecu._last_inputs
        st = ecu.core
        verdict = st.verdict
        cal = ecu._core_cal
        if (
            inputs is None
            or verdict is None
            or verdict.inputs is not inputs
            or verdict.cal is not cal
            or st.safety.state is not _ENGAGED
            # the inputs are reused: what `EcuApp._cycle` compares, with no event pending at all
            or ecu._unlatch_pending
            or ecu._stall_pending
            or ecu._internal_pending
            or ecu._guard_pending
            or inputs.unlatch
            or inputs.loop_stall
            or inputs.internal_error
            or inputs.tx_guard_trip
            or ecu.stats.overrun_streak != inputs.overrun_streak
            # driving, not shifting, and no gear confirmation pending
            or not (verdict.wanted_gear == st.gear_request == inputs.gear_engaged)
            or st.gear_wait_s != _INF
            or st.shift_hold_s != _INF
            # the faults reported stay those reported
            or (int(verdict.faults) | int(st.safety.latched)) != ecu._reported_faults
            # the safety state machine stands still on these inputs
            or safety_transition(st.safety, inputs, verdict.active, cal) is not st.safety
        ):
            self._run_until = -_INF
            return False
        node = ecu.node
        if node._rx_frames != node._quiet_rx_frames:
            self._run_until = -_INF
            return False
        # Not quiet from: the inputs' expiry (reused while now <= valid_until), the next command and
        # status, the node's next timer.
        self._run_until = min(
            math.nextafter(ecu._inputs_valid_until_s, _INF),
            ecu._next_command_s,
            ecu._next_status_s,
            node._quiet_until_s,
        )
        if not now_s < self._run_until:
            return False
        self._core0 = st
        self._inputs = inputs
        self._ctl = st.controller
        self._steer = st.steer_angle_rad
        self._v_est = st.speed_est_mps
        self._trusted_t = st.speed_trusted_t_s
        self._advanced = False
        a_req = inputs.request_accel_mps2
        if inputs.gear_engaged == _REVERSE:
            a_lim = reverse_accel_limit_mps2(inputs.speed_mps)
            if a_req > a_lim:
                a_req = a_lim
        self._a_req = a_req
        self._accel_along = verdict.accel_along_mps2
        return True

    def _advance(self, now_s: float) -> None:
        """One quiet cycle at `now_s`: what `core._step_engaged` changes when driving on reused inputs."""
        inputs = self._inputs
        core0 = self._core0
        assert inputs is not None and core0 is not None and self._ctl is not None
        ctl_prev = self._ctl
        cal = self.ecu._core_cal
        verdict = core0.verdict
        assert verdict is not None
        self._ctl = controller_cycle(
            ctl_prev,
            now_s,
            self._a_req,
            self._accel_along,
            inputs.speed_mps,
            True,  # closed_loop
            True,  # throttle_allowed
            False,  # hold
            cal,
        )[0]
        if verdict.steer_requested:
            dt = step_dt_s(ctl_prev.t_s, now_s)
            self._steer = steer_step(self._steer, inputs.request_steer_angle_rad, dt, cal)
        else:
            self._steer = clamp_steer(inputs.steer_angle_meas_rad, self._steer, cal)
        if verdict.usable:
            self._v_est, self._trusted_t = inputs.speed_mps, now_s
        self._advanced = True

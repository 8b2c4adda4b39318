"""The host's side of the CANopen link to the ECU, as two modules around the controllers.

`EcuRx` polls the link at the start of a cycle and publishes the ECU's status; `EcuTx` ends the
cycle: it sends the newest control request with the alive counter and produces the heartbeat the
ECU's watchdog consumes (DESIGN section 4; seed 000 section 2.3: the host sends requests, the ECU
acts on them only while they keep coming).

EcuTx is the host's last check before the ECU: it sends a control request only if it is fresh
(`REQUEST_MAX_AGE_S`); if the controller has gone silent it asks for a controlled stop (STOP flag,
zero acceleration) instead of repeating an old request, and it adds STOP whenever the supervisor
asked for one. The heartbeat stops only when the host itself stops (or a test mutes it): a host
whose controller failed is still alive, and says so while it stops the car in an orderly way.

Engagement is an edge (ecu.safety): the ECU goes from READY to ENGAGED only when the ENGAGE flag
rises while it is ready. `EngagePress` turns the mission's wish into that edge: each time the
mission starts asking for ENGAGE, the request is pending until the ECU reports ENGAGED; while it
is pending and the ECU reports READY without any fault, the host presses: one request without
ENGAGE, then with it, again after `ENGAGE_RETRY_S` if the ECU stayed READY. A wish that was
consumed (the ECU engaged once) is never pressed again on its own: after a DISABLE, a driver
override, an ECU reset or an NMT restart the flag stays a level that engages nothing, until the
mission asks anew.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from bywire.host.modules.messages import (
    CONTROL,
    ECU_REQUEST,
    ECU_STATUS,
    MISSION,
    ODOMETRY,
    ControlRequest,
    EcuRequestSent,
    EcuStatusReport,
    MissionCommand,
    Odometry,
)
from bywire.host.runtime.module import Module, ModuleContext
from bywire.host.runtime.topics import STOP_REQUEST
from bywire.host.trace import CONTROLLERS, TraceWriter
from bywire.protocol.canopen_link.host_master import HostMaster
from bywire.protocol.canopen_link.nmt import NmtState
from bywire.protocol.ecu_types import EcuState, RequestFlags
from bywire.protocol.host_link import HostRequest

# 5 host periods: older control requests are not sent (a controlled stop is asked for instead).
# A configuration whose controller runs slower, or behind a slower producer, may allow more
# (`ecu_tx` params.request_max_age_ms); the ECU's heartbeat watchdog is independent of it.
REQUEST_MAX_AGE_S = 0.1
NMT_START_RETRY_S = 0.2
# A press the ECU did not take (a request lost on the link, a precondition gone for a moment) is
# repeated after this long: well over the 20 ms status period and the 50 Hz request period.
ENGAGE_RETRY_S = 0.3
_READY, _ENGAGED = int(EcuState.READY), int(EcuState.ENGAGED)


class EngagePress:
    """The ENGAGE flag to send, from the mission's wish and the ECU's reported state (see the
    module docstring). Pure: `flag(want, state, faults, now_s)` once per request sent."""

    def __init__(self) -> None:
        self.pending = False
        self._want_prev = False
        self._released = False  # the last request sent had ENGAGE cleared for a press
        self._pressed_s = -math.inf

    def flag(self, want: bool, state: int | None, faults: int, now_s: float) -> bool:
        if want and not self._want_prev:
            self.pending = True
        self._want_prev = want
        if not want:
            self.pending = self._released = False
            return False
        if state == _ENGAGED:
            self.pending = False
        if not (self.pending and state == _READY and faults == 0):
            self._released = False
            return True
        if self._released:  # the release went out last request: now the rising edge
            self._released = False
            self._pressed_s = now_s
            return True
        if now_s - self._pressed_s >= ENGAGE_RETRY_S:
            self._released = True
            return False
        return True


class EcuRx(Module):
    def __init__(self, link: HostMaster) -> None:
        self.link = link
        self._last_rx_s: float | None = None

    def start(self, ctx: ModuleContext) -> None:
        self.link.set_nmt_state(NmtState.OPERATIONAL)  # this host is in control: the ECU may engage

    def step(self, ctx: ModuleContext) -> None:
        now = ctx.now_s
        self.link.poll(now)
        latest = self.link.latest_status()
        operational = self.link.ecu_nmt_state(now) is NmtState.OPERATIONAL
        if latest is None:
            report = EcuStatusReport(now, False, False, math.nan, 0, 0, operational, 0.0, 0.0, 0.0, 0.0, 0.0)
        else:
            status, rx_s = latest
            fresh = self._last_rx_s is None or rx_s > self._last_rx_s
            self._last_rx_s = rx_s
            report = EcuStatusReport(
                t_s=now,
                valid=True,
                fresh=fresh,
                rx_s=rx_s,
                state=int(status.state),
                faults=int(status.faults),
                nmt_operational=operational,
                speed_mps=status.speed_mps,
                accel_mps2=status.accel_mps2,
                throttle_pct=status.throttle_pct,
                brake_bar=status.brake_bar,
                steer_angle_rad=status.steer_angle_rad,
            )
        ctx.publish(ECU_STATUS, report)


class EcuTx(Module):
    def __init__(
        self,
        link: HostMaster,
        trace: TraceWriter | None = None,
        t0_s: Callable[[], float] = lambda: 0.0,
        request_max_age_s: float = REQUEST_MAX_AGE_S,
        heartbeat_muted: Callable[[float], bool] | None = None,
        heartbeat_sent: Callable[[float], None] | None = None,
    ) -> None:
        self.link = link
        # A test harness's door to a host that keeps requesting but has lost its heartbeat thread.
        self.heartbeat_muted = heartbeat_muted
        self.heartbeat_sent = heartbeat_sent
        self.request_max_age_s = request_max_age_s
        self.trace = trace
        self.t0_s = t0_s  # read at each step: a module is built before a HIL run's start fixes t0
        self.counter = 0
        self._next_nmt_start_s = -math.inf
        self.engage_press = EngagePress()

    def step(self, ctx: ModuleContext) -> None:
        now = ctx.now_s
        status: EcuStatusReport | None = ctx.latest(ECU_STATUS)
        if status is not None and not status.nmt_operational and now >= self._next_nmt_start_s:
            # CANopen start-up: the master puts the ECU node into OPERATIONAL (and again after a reset).
            self.link.start_ecu()
            self._next_nmt_start_s = now + NMT_START_RETRY_S
        req: ControlRequest | None = ctx.latest(CONTROL)
        mission: MissionCommand | None = ctx.latest(MISSION)
        if req is not None and now - req.t_s <= self.request_max_age_s:
            accel, steer, flags, age_ms = (
                req.accel_mps2,
                req.steer_rad,
                RequestFlags(req.flags),
                (now - req.t_s) * 1e3,
            )
        else:
            accel, steer, age_ms = 0.0, 0.0, -1.0
            flags = RequestFlags.STOP | (RequestFlags.ENGAGE if mission is not None and mission.engage else 0)
        if ctx.latest(STOP_REQUEST) is not None:
            flags |= RequestFlags.STOP
        state = status.state if status is not None and status.valid else None
        engage = self.engage_press.flag(
            bool(flags & RequestFlags.ENGAGE), state, status.faults if status is not None else -1, now
        )
        flags = flags | RequestFlags.ENGAGE if engage else flags & ~RequestFlags.ENGAGE
        self.counter = (self.counter + 1) & 0xFF
        self.link.send_request(
            HostRequest(accel_mps2=accel, steer_angle_rad=steer, flags=flags, counter=self.counter)
        )
        heartbeat = self.heartbeat_muted is None or not self.heartbeat_muted(now)
        if heartbeat:
            self.link.tick(now)
            if self.heartbeat_sent is not None:
                self.heartbeat_sent(now)
        ctx.publish(
            ECU_REQUEST,
            EcuRequestSent(now, accel, steer, int(flags), self.counter, round(age_ms, 3), heartbeat),
        )
        if self.trace is not None:
            odo: Odometry | None = ctx.latest(ODOMETRY)
            controller = req.controller if req is not None and age_ms >= 0 else "none"
            self.trace.append(
                (
                    now - self.t0_s(),
                    accel,
                    steer,
                    float(int(flags)),
                    float(status.state if status is not None else 0),
                    float(status.faults if status is not None else 0),
                    status.speed_mps if status is not None else 0.0,
                    req.v_des_mps if req is not None else math.nan,
                    odo.odometer_m if odo is not None else 0.0,
                    float(CONTROLLERS.index(controller)),
                    req.gap_m if req is not None else math.nan,
                )
            )

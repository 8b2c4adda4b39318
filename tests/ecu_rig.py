"""The ECU application on its buses with a hand-played car and host around it, for tests.

`Rig`: lockstep on a simulated clock (SIL buses): the gateway side is played with the vehicle codec,
the host side by the CANopen master; one simulated millisecond per `tick`. The ECU's loop can be
stalled (not stepped) while everything else goes on, and any sender can freeze on its last frame.

`WallRig`: the same on the wall clock: the ECU runs under the real `CyclicExecutive` in a thread, the
car and the host in another, on python-can `virtual` buses; what a foreign CANopen master or a
frozen cycle meets on a real machine.
"""

from __future__ import annotations

import contextlib
import threading
import time
import uuid
from collections.abc import Callable
from typing import Any

import can

from bywire.clock import SimClock, WallClock
from bywire.ecu.app import EcuApp
from bywire.ecu.calibration import default_calibration
from bywire.ecu.executive import CycleStats, CyclicExecutive
from bywire.hil.sil_bus import SimVirtualBus
from bywire.protocol.canopen_link.host_master import HostMaster
from bywire.protocol.canopen_link.nmt import NmtState
from bywire.protocol.ecu_types import EcuState, EstopMode, RequestFlags
from bywire.protocol.host_link import HostRequest
from bywire.protocol.vehicle_can import (
    DbwCommand,
    DriverInputs,
    EstopRadio,
    Motion,
    SteerReport,
    VehicleCodec,
    VehicleFrame,
    VehicleTx,
    WheelSpeeds,
)
from bywire.protocol.vehicle_rx import VehicleRx

ENGAGE = RequestFlags.ENGAGE
RELEASED = RequestFlags.NONE


class _Car:
    """What both rigs play: the gateway's reports, the E-stop radio and the host's requests."""

    def __init__(self) -> None:
        self.codec = VehicleCodec()
        self.tx = VehicleTx(self.codec)
        self.gateway: can.BusABC
        self.host: HostMaster
        self.gw_rx = VehicleRx(self.codec, accept=["DBW_Command"], max_age_cycles=None)
        self.estop = EstopMode.RUN
        self.driver_brake = False
        self.arm = False
        self.speed_mps = 10.0
        self.flags = ENGAGE
        self.accel = 0.5
        self.counter = 0
        self.commands: list[tuple[float, DbwCommand]] = []
        self.stuck: set[str] = set()  # senders frozen on their last frame (DBC message names)
        self.request_stuck = False  # the host repeats its last request frame (same alive counter)
        self.host_silent = False  # the host sends nothing at all (heartbeat and requests)
        self._last: dict[str, can.Message] = {}

    def frames(self, k: int) -> list[tuple[str, VehicleFrame]]:
        out: list[tuple[str, VehicleFrame]] = []
        if k % 10 == 0:
            v = self.speed_mps
            out += [
                ("GW_WheelSpeeds", WheelSpeeds(v, v, v, v)),
                ("GW_Motion", Motion(0.0, 0.0, 0.0)),
                (
                    "GW_Driver",
                    DriverInputs(self.driver_brake, 0.0, 30.0 if self.driver_brake else 0.0, self.arm),
                ),
                ("GW_Steer", SteerReport(0.0, 0.0)),
            ]
        if k % 50 == 0:
            out.append(("ESTOP_Radio", EstopRadio(self.estop)))
        return out

    def encode(self, name: str, frame: VehicleFrame, now_s: float) -> can.Message:
        if name in self.stuck and name in self._last:
            old = self._last[name]
            msg = can.Message(arbitration_id=old.arbitration_id, data=bytes(old.data), is_extended_id=False)
            msg.timestamp = now_s
            return msg
        msg = self.tx.encode(frame, timestamp_s=now_s)
        self._last[name] = msg
        return msg

    def gateway_and_host(self, k: int, now: float) -> None:
        """Millisecond k after the ECU's cycle: the gateway reads the commands, and every 20 ms the
        host polls, (re)starts the ECU node, sends its request and its heartbeat."""
        while (msg := self.gateway.recv(0)) is not None:
            frame = self.gw_rx.feed(msg, now, now)
            if isinstance(frame, DbwCommand):
                self.commands.append((now, frame))
        if k % 20 == 0 and not self.host_silent:
            self.host.poll(now)
            if self.host.ecu_nmt_state(now) is not NmtState.OPERATIONAL:
                self.host.start_ecu()
            self.host.send_request(self.request())
            self.host.tick(now)

    def request(self) -> HostRequest:
        if not self.request_stuck:
            self.counter = (self.counter + 1) & 0xFF
        return HostRequest(self.accel, 0.0, self.flags, self.counter)


class Rig(_Car):
    """ECU + a hand-played gateway + a CANopen host master, one simulated millisecond per `tick`."""

    def __init__(self, calibration: object = "default") -> None:
        super().__init__()
        self.clock = SimClock(0.0)
        tag = uuid.uuid4().hex[:6]
        self.buses: list[can.BusABC] = []
        self.vehicle_ch, self.link_ch = f"veh-{tag}", f"link-{tag}"
        cal = default_calibration() if calibration == "default" else calibration
        self.cal = cal
        self.ecu = self.new_ecu()
        self.gateway = self._bus(self.vehicle_ch)
        self.host = HostMaster(self._bus(self.link_ch), self.clock)
        self.host.set_nmt_state(NmtState.OPERATIONAL)
        self.stalled = False  # the ECU's loop is not stepped (a frozen process)

    def new_ecu(self) -> EcuApp:
        """A freshly booted ECU on the rig's buses (a reset: nothing of the old one survives)."""
        return EcuApp(
            self._bus(self.vehicle_ch),
            self._bus(self.link_ch),
            self.clock,
            self.cal,  # type: ignore[arg-type]
            None if self.cal is not None else "no calibration",
        )

    def _bus(self, channel: str) -> SimVirtualBus:
        bus = SimVirtualBus(channel, self.clock)
        self.buses.append(bus)
        return bus

    def close(self) -> None:
        for bus in self.buses:
            bus.shutdown()

    def tick(self) -> None:
        now = self.clock.now()
        k = round(now * 1000)
        for name, frame in self.frames(k):
            self.gateway.send(self.encode(name, frame, now))
        if not self.stalled:
            self.ecu.step(now)
        self.gateway_and_host(k, now)
        self.clock.advance_to(now + 0.001)

    def run(self, seconds: float, until: Callable[[], bool] | None = None) -> float:
        """Run `seconds` (or until `until()`); returns the simulated time it took."""
        t0 = self.clock.now()
        for _ in range(round(seconds * 1000)):
            self.tick()
            if until is not None and until():
                break
        return self.clock.now() - t0

    def press_engage(self) -> None:
        """What a host does to engage: ENGAGE released for a request, then raised."""
        self.flags = RELEASED
        self.run(0.05)
        self.flags = ENGAGE
        self.run(0.05)

    def engaged(self) -> Rig:
        self.flags = RELEASED
        self.run(0.3)
        self.press_engage()
        assert self.state is EcuState.ENGAGED, self.state
        return self

    @property
    def state(self) -> EcuState:
        return self.ecu.core.safety.state


class WallRig(_Car):
    """The ECU under its real-time executive on the wall clock, with the car and the host in a
    second thread (1 ms ticks) on python-can `virtual` buses. Use as a context manager.
    `link_bus`: the ECU's end of a host link of its own (a host in another process; then set
    `host_silent`, the rig's own host master is not on it)."""

    def __init__(
        self,
        calibration: object = "default",
        *,
        step_hook: Callable[[float], None] | None = None,
        link_bus: can.BusABC | None = None,
    ) -> None:
        super().__init__()
        tag = uuid.uuid4().hex[:6]
        self.vehicle_ch, self.link_ch = f"wveh-{tag}", f"wlink-{tag}"
        self.clock = WallClock()
        cal = default_calibration() if calibration == "default" else calibration
        self.buses: list[can.BusABC] = []
        if link_bus is not None:
            self.buses.append(link_bus)
        self.ecu = EcuApp(
            self._bus(self.vehicle_ch),
            link_bus if link_bus is not None else self._bus(self.link_ch),
            self.clock,
            cal,  # type: ignore[arg-type]
            None if cal is not None else "no calibration",
            stats=CycleStats(),
        )
        self.step_hook = step_hook  # called inside the ECU's cycle, before the ECU's own step
        self.gateway = self._bus(self.vehicle_ch)
        self.host_bus = self._bus(self.link_ch)
        self.host = HostMaster(self.host_bus, self.clock)
        self.host.set_nmt_state(NmtState.OPERATIONAL)
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._lock = threading.Lock()

    def _bus(self, channel: str) -> can.BusABC:
        bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        self.buses.append(bus)
        return bus

    def __enter__(self) -> WallRig:
        executive = CyclicExecutive(0.001, self.clock, self._ecu_step, self.ecu.stats)
        self._threads = [
            threading.Thread(target=executive.run, kwargs={"stop": self._stop.is_set}, daemon=True),
            threading.Thread(target=self._car_loop, daemon=True),
        ]
        for t in self._threads:
            t.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(5.0)
        for bus in self.buses:
            with contextlib.suppress(Exception):
                bus.shutdown()

    def _ecu_step(self, deadline_s: float) -> None:
        if self.step_hook is not None:
            self.step_hook(deadline_s)
        self.ecu.step(deadline_s)

    def _car_loop(self) -> None:
        t0 = self.clock.now()
        k = 0
        while not self._stop.is_set():
            self.clock.sleep_until(t0 + k * 0.001)
            now = self.clock.now()
            with self._lock:
                for name, frame in self.frames(k):
                    msg = self.encode(name, frame, now)
                    msg.timestamp = time.time()  # python-can stamps on the epoch clock
                    self.gateway.send(msg)
                self.gateway_and_host(k, now)
            k += 1

    def wait(self, seconds: float) -> None:
        time.sleep(seconds)

    def wait_for(self, pred: Callable[[], bool], timeout_s: float) -> bool:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if pred():
                return True
            time.sleep(0.005)
        return pred()

    def _release_seen(self) -> bool:
        latest = self.ecu.node.latest_request()
        return latest is not None and latest[0].flags == RELEASED

    def engage(self, timeout_s: float = 5.0) -> None:
        self.flags = RELEASED
        assert self.wait_for(lambda: self.state is EcuState.READY, timeout_s), self.state
        # Engagement is an edge between fresh requests: the ECU must have taken a released one
        # before the press (on a loaded machine 0.1 s of waiting did not always see one sent).
        assert self.wait_for(self._release_seen, timeout_s), self.ecu.node.latest_request()
        self.flags = ENGAGE
        assert self.wait_for(lambda: self.state is EcuState.ENGAGED, timeout_s), (
            self.state,
            self.ecu.last_command,
        )

    @property
    def state(self) -> EcuState:
        return self.ecu.core.safety.state

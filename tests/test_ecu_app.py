"""The ECU application on its buses (no plant): frames in, core, frames and PDOs out, SDO services.

The gateway side is played by hand with the vehicle codec, the host side by the CANopen master,
all on in-process virtual buses stepped in lockstep on a simulated clock.
"""

from __future__ import annotations

import dataclasses
import json
import uuid
from collections.abc import Iterator

import can
import pytest

from bywire.clock import SimClock
from bywire.ecu.app import EcuApp
from bywire.ecu.calibration import _crc32, calibration_to_dict, default_calibration, dumps_calibration
from bywire.hil.sil_bus import SimVirtualBus
from bywire.protocol.canopen_node import EcuRefusedError, HostMaster, NmtState
from bywire.protocol.ecu_types import EcuState, EstopMode, Fault, RequestFlags
from bywire.protocol.host_link import HostRequest
from bywire.protocol.vehicle_can import (
    DbwCommand,
    DriverInputs,
    EstopRadio,
    Motion,
    SteerReport,
    VehicleCodec,
    VehicleRx,
    VehicleTx,
    WheelSpeeds,
)


class Rig:
    """ECU + a hand-played gateway + a CANopen host master, one simulated millisecond per `run` step."""

    def __init__(self, calibration: object = "default") -> None:
        self.clock = SimClock(0.0)
        tag = uuid.uuid4().hex[:6]
        self.buses: list[can.BusABC] = []
        vehicle, link = f"veh-{tag}", f"link-{tag}"
        cal = default_calibration() if calibration == "default" else calibration
        self.ecu = EcuApp(
            self._bus(vehicle),
            self._bus(link),
            self.clock,
            cal,  # type: ignore[arg-type]
            None if cal is not None else "no calibration",
        )
        self.gateway = self._bus(vehicle)
        self.host = HostMaster(self._bus(link), self.clock)
        self.host.set_nmt_state(NmtState.OPERATIONAL)
        self.codec = VehicleCodec()
        self.tx = VehicleTx(self.codec)
        self.gw_rx = VehicleRx(self.codec, accept=["DBW_Command"])
        self.estop = EstopMode.RUN
        self.driver_brake = False
        self.speed_mps = 10.0
        self.flags = RequestFlags.ENGAGE
        self.accel = 0.5
        self.commands: list[DbwCommand] = []
        self.counter = 0

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
        if k % 10 == 0:
            for frame in (
                WheelSpeeds(self.speed_mps, self.speed_mps, self.speed_mps, self.speed_mps),
                Motion(0.0, 0.0, 0.0),
                DriverInputs(self.driver_brake, 0.0, 30.0 if self.driver_brake else 0.0),
                SteerReport(0.0, 0.0),
            ):
                self.gateway.send(self.tx.encode(frame, timestamp_s=now))
        if k % 50 == 0:
            self.gateway.send(self.tx.encode(EstopRadio(self.estop), timestamp_s=now))
        self.ecu.step(now)
        while (msg := self.gateway.recv(0)) is not None:
            frame = self.gw_rx.feed(msg, now)
            if isinstance(frame, DbwCommand):
                self.commands.append(frame)
        if k % 20 == 0:
            self.host.poll(now)
            if self.host.ecu_nmt_state(now) is not NmtState.OPERATIONAL:
                self.host.start_ecu()
            self.counter = (self.counter + 1) & 0xFF
            self.host.send_request(HostRequest(self.accel, 0.0, self.flags, self.counter))
            self.host.tick(now)
        self.clock.advance_to(now + 0.001)

    def run(self, seconds: float) -> None:
        for _ in range(round(seconds * 1000)):
            self.tick()

    @property
    def state(self) -> EcuState:
        return self.ecu.core.safety.state


@pytest.fixture
def rig() -> Iterator[Rig]:
    r = Rig()
    yield r
    r.close()


def test_engages_and_commands_throttle_at_100_hz(rig: Rig) -> None:
    rig.run(1.0)
    assert rig.state is EcuState.ENGAGED
    assert 95 <= len(rig.commands) <= 101  # DBW_Command every 10 ms
    last = rig.commands[-1]
    assert (
        last.engage and last.ecu_state is EcuState.ENGAGED and last.throttle_pct > 0 and last.brake_bar == 0
    )
    status = rig.host.latest_status()
    assert status is not None and status[0].state is EcuState.ENGAGED
    assert status[0].speed_mps == pytest.approx(10.0, abs=0.01)


def test_status_counter_advances(rig: Rig) -> None:
    rig.run(0.5)
    first = rig.host.latest_status()
    rig.run(0.1)
    second = rig.host.latest_status()
    assert first is not None and second is not None and first[0].counter != second[0].counter


def test_disable_latches_until_sdo_unlatch_and_run(rig: Rig) -> None:
    rig.run(0.5)
    rig.estop = EstopMode.DISABLE
    rig.speed_mps = 0.0
    rig.run(1.0)
    assert rig.state is EcuState.DISABLED
    emcys = rig.host.pop_emcys()
    assert any(e.record.faults & Fault.ESTOP_DISABLE for e in emcys)
    rig.estop = EstopMode.RUN
    rig.run(0.5)
    assert rig.state is EcuState.DISABLED, "RUN alone must not unlatch a DISABLE"
    rig.host.unlatch(idle=rig.tick)
    rig.run(0.2)
    assert rig.state in (EcuState.READY, EcuState.ENGAGED)


def test_calibration_over_sdo_refused_while_actuating_accepted_when_ready(rig: Rig) -> None:
    rig.run(0.5)
    assert rig.state is EcuState.ENGAGED
    new = dataclasses.replace(default_calibration(), version=default_calibration().version + 1)
    with pytest.raises(EcuRefusedError, match="not actuating"):
        rig.host.write_calibration(dumps_calibration(new), idle=rig.tick)
    rig.flags = RequestFlags.NONE  # the host lets go: controlled stop, then re-arm to READY
    rig.speed_mps = 0.0
    rig.run(1.0)
    rig.flags = RequestFlags.REARM
    rig.run(0.2)
    rig.flags = RequestFlags.NONE
    rig.run(0.2)
    assert rig.state is EcuState.READY
    rig.host.write_calibration(dumps_calibration(new), idle=rig.tick)
    assert rig.ecu.calibration is not None and rig.ecu.calibration.version == new.version
    bad = calibration_to_dict(new)
    bad["brake_map"]["bar"] = list(reversed(bad["brake_map"]["bar"]))  # not monotone, CRC still right
    bad["crc32"] = _crc32(bad)
    with pytest.raises(EcuRefusedError, match=r"brake_map\.bar"):
        rig.host.write_calibration(json.dumps(bad).encode(), idle=rig.tick)
    assert rig.ecu.calibration.version == new.version  # the refused one changed nothing


def test_no_calibration_stays_off_and_passive() -> None:
    rig = Rig(calibration=None)
    try:
        rig.run(1.0)
        assert rig.state is EcuState.OFF
        assert all(not c.engage and c.throttle_pct == 0 and c.brake_bar == 0 for c in rig.commands)
        status = rig.host.latest_status()
        assert status is not None and status[0].faults & Fault.CALIBRATION_INVALID
    finally:
        rig.close()


def test_driver_brake_hands_over_within_two_frames(rig: Rig) -> None:
    rig.run(0.5)
    t_press = rig.clock.now()
    rig.driver_brake = True
    while rig.state is EcuState.ENGAGED:
        rig.tick()
    assert rig.state is EcuState.MANUAL
    assert rig.clock.now() - t_press <= 0.021

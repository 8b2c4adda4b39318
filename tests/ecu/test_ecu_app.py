"""The ECU application on its buses (no plant): frames in, core, frames and PDOs out, SDO services.

The gateway side is played by hand with the vehicle codec, the host side by the CANopen master,
all on in-process virtual buses stepped in lockstep on a simulated clock.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Iterator

import pytest
from ecu_rig import Rig

from bywire.ecu.calibration import _crc32, calibration_to_dict, default_calibration, dumps_calibration
from bywire.protocol.canopen_link.host_master import EcuRefusedError
from bywire.protocol.ecu_types import EcuState, EstopMode, Fault, RequestFlags


@pytest.fixture
def rig() -> Iterator[Rig]:
    r = Rig()
    yield r
    r.close()


def test_engages_and_commands_throttle_at_100_hz(rig: Rig) -> None:
    rig.engaged()
    rig.run(0.6)
    assert rig.state is EcuState.ENGAGED
    assert 95 <= len(rig.commands) <= 101  # DBW_Command every 10 ms
    _, last = rig.commands[-1]
    assert (
        last.engage and last.ecu_state is EcuState.ENGAGED and last.throttle_pct > 0 and last.brake_bar == 0
    )
    status = rig.host.latest_status()
    assert status is not None and status[0].state is EcuState.ENGAGED
    assert status[0].speed_mps == pytest.approx(10.0, abs=0.01)


def test_status_counter_advances(rig: Rig) -> None:
    rig.engaged()
    first = rig.host.latest_status()
    rig.run(0.1)
    second = rig.host.latest_status()
    assert first is not None and second is not None and first[0].counter != second[0].counter


def test_disable_latches_until_sdo_unlatch_and_the_arm_button(rig: Rig) -> None:
    rig.engaged()
    rig.estop = EstopMode.DISABLE
    rig.speed_mps = 0.0
    rig.run(1.0)
    assert rig.state is EcuState.DISABLED
    emcys = rig.host.pop_emcys()
    assert any(e.record.faults & Fault.ESTOP_DISABLE for e in emcys)
    with pytest.raises(EcuRefusedError, match="still says DISABLE"):
        rig.host.unlatch(idle=rig.tick)
    rig.estop = EstopMode.RUN
    rig.run(0.5)
    assert rig.state is EcuState.DISABLED, "RUN alone must not unlatch a DISABLE"
    rig.host.unlatch(idle=rig.tick)
    rig.run(0.5)
    assert rig.state is EcuState.DISABLED, "the unlatch alone must not re-arm"
    rig.arm = True
    rig.run(0.1)
    rig.arm = False
    assert rig.state is EcuState.READY, "the arm button completes the re-arm"
    rig.run(0.5)
    assert rig.state is EcuState.READY, "ENGAGE held as a level must not engage"
    rig.press_engage()
    assert rig.state is EcuState.ENGAGED


def test_calibration_over_sdo_refused_while_actuating_accepted_when_ready(rig: Rig) -> None:
    rig.engaged()
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
        assert all(not c.engage and c.throttle_pct == 0 and c.brake_bar == 0 for _, c in rig.commands)
        status = rig.host.latest_status()
        assert status is not None and status[0].faults & Fault.CALIBRATION_INVALID
    finally:
        rig.close()


def test_driver_brake_hands_over_within_two_frames(rig: Rig) -> None:
    rig.engaged()
    t_press = rig.clock.now()
    rig.driver_brake = True
    while rig.state is EcuState.ENGAGED:
        rig.tick()
    assert rig.state is EcuState.MANUAL
    assert rig.clock.now() - t_press <= 0.021

"""The safety authority on its buses, attacked from outside: a stalled loop, a frozen sender, an
exception inside a cycle, a broken core behind the transmit guard, a host that re-arms itself, and
a foreign CANopen master that writes every writable entry out of range in every state.

Spec: ecu/safety.py and ecu/app.py docstrings (DESIGN section 4). The rigs are in tests/ecu_rig.py.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

import can
import canopen
import pytest
from canopen.sdo.exceptions import SdoAbortedError
from ecu_rig import ENGAGE, RELEASED, Rig, WallRig
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import bywire.ecu.app as app_module
from bywire.ecu.app import LOOP_STALL_MAX_GAP_S
from bywire.ecu.core import core_step
from bywire.protocol.canopen_link.dictionary import (
    ABORT_DEVICE_STATE,
    ABORT_LOCAL_CONTROL,
    ABORT_VALUE_RANGE,
    ABORT_VALUE_TOO_HIGH,
    ABORT_VALUE_TOO_LOW,
    EDS_PATH,
    MAX_HOST_HEARTBEAT_TIMEOUT_MS,
    MAX_PRODUCER_HEARTBEAT_MS,
    MAX_REQUEST_DEADLINE_MS,
    MAX_TPDO_EVENT_TIMER_MS,
    load_ecu_od,
)
from bywire.protocol.canopen_link.host_master import EcuRefusedError
from bywire.protocol.canopen_link.nmt import NmtCommand
from bywire.protocol.ecu_types import EcuState, EstopMode, Fault, RequestFlags


@pytest.fixture
def rig() -> Iterator[Rig]:
    r = Rig()
    yield r
    r.close()


def _fault_bits(rig: Rig) -> Fault:
    return rig.ecu.last_command.faults_latched if rig.ecu.last_command is not None else Fault.NONE


# --- a stalled loop ------------------------------------------------------------------------------


@pytest.mark.parametrize("stall_ms", [5, 10, 15, 20, 21, 25, 40, 60, 100, 300, 1500, 2000])
def test_a_loop_stall_longer_than_the_bound_is_a_stop_fault_of_its_own(rig: Rig, stall_ms: int) -> None:
    # Everything else goes on (gateway, E-stop, host): after the stall every input looks fresh
    # again, because it is. The stall itself must be judged.
    rig.engaged()
    rig.stalled = True
    rig.run(stall_ms / 1000.0)
    rig.stalled = False
    rig.run(0.05)
    if stall_ms / 1000.0 + 0.001 > LOOP_STALL_MAX_GAP_S + 1e-9:  # the gap spans the stall and a cycle
        assert rig.state is EcuState.SAFE_STOP
        assert _fault_bits(rig) & Fault.LOOP_STALL
        assert rig.ecu.loop_stalls == 1 and rig.ecu.internal_fault_events == 1
    else:
        assert rig.state is EcuState.ENGAGED and rig.ecu.loop_stalls == 0


def test_the_safe_outcome_is_monotone_in_the_stall() -> None:
    outcomes = []
    for stall_ms in range(0, 61, 3):
        r = Rig()
        try:
            r.engaged()
            r.stalled = True
            r.run(stall_ms / 1000.0)
            r.stalled = False
            r.run(0.05)
            outcomes.append(r.state is EcuState.SAFE_STOP)
        finally:
            r.close()
    first = outcomes.index(True)
    assert all(outcomes[first:]) and not any(outcomes[:first])  # once stopping, always stopping


@pytest.mark.parametrize("stall_ms", [5, 30, 100, 300, 2000])
def test_a_frozen_cycle_on_the_wall_clock_executive(stall_ms: int) -> None:
    """One cycle of the real executive freezes; the outcome is judged by what the ECU measured:
    LOOP_STALL exactly when its largest gap between cycles exceeded the bound (a loaded machine may
    stall a 5 ms freeze past it, and then stopping is right), and SAFE_STOP with it. The rig's car
    and host are a thread of this process: starved by a loaded machine, their frames go stale and
    the ECU stops for that (a timeout), which is right too, but never for a loop stall it did not
    measure."""
    freeze = {"armed": False, "done": False}

    def hook(_deadline: float) -> None:
        if freeze["armed"] and not freeze["done"]:
            time.sleep(stall_ms / 1000.0)
            freeze["done"] = True

    with WallRig(step_hook=hook) as rig:
        rig.engage()
        rig.wait(0.2)
        freeze["armed"] = True
        assert rig.wait_for(lambda: freeze["done"], 10.0)
        rig.wait(0.2)
    # read once the rig has stopped: the gap, the count and the latch are then of the same cycles
    state, faults = rig.state, _fault_bits(rig)  # type: ignore[arg-type]
    stalled = rig.ecu.max_cycle_gap_s > LOOP_STALL_MAX_GAP_S
    assert stalled == (rig.ecu.loop_stalls > 0)
    if stall_ms / 1000.0 > LOOP_STALL_MAX_GAP_S:
        assert stalled
    assert bool(faults & Fault.LOOP_STALL) == stalled
    if stalled:
        assert state is EcuState.SAFE_STOP
    elif state is not EcuState.ENGAGED:
        starved = Fault.VEHICLE_TIMEOUT | Fault.HOST_HEARTBEAT | Fault.REQUEST_INVALID | Fault.ESTOP_TIMEOUT
        assert state is EcuState.SAFE_STOP and faults and not faults & ~starved, (state, faults)


# --- frozen senders: a repeated counter is never fresh ---------------------------------------------

# What each sender's freeze must make the ECU see, and the timeout it is bounded by (DBC cycle time x
# the receiver's timeout cycles; the request deadline 0x1400sub5).
FROZEN = {
    "ESTOP_Radio": ("estop_fresh", 0.5),
    "GW_WheelSpeeds": ("vehicle", 0.1),
    "GW_Motion": ("vehicle", 0.1),
    "GW_Driver": ("vehicle", 0.1),
    "GW_Steer": ("vehicle", 0.1),
    "host request": ("request_fresh", 0.1),
}


def _fresh(rig: Rig, what: str) -> bool:
    inp = rig.ecu._last_inputs
    assert inp is not None
    if what == "vehicle":
        return inp.vehicle_fresh and not inp.vehicle_corrupt
    return bool(getattr(inp, what))


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(sender=st.sampled_from(sorted(FROZEN)), phase_ms=st.integers(0, 99), before_ms=st.integers(300, 700))
def test_a_sender_frozen_on_its_last_frame_is_caught_within_its_timeout(
    sender: str, phase_ms: int, before_ms: int
) -> None:
    what, timeout_s = FROZEN[sender]
    rig = Rig()
    try:
        rig.engaged()
        rig.run((before_ms + phase_ms) / 1000.0)  # freeze at any phase of the sender's period
        assert _fresh(rig, what)
        t_freeze = rig.clock.now()
        if sender == "host request":
            rig.request_stuck = True
        else:
            rig.stuck.add(sender)
        took = rig.run(timeout_s + 0.5, until=lambda: not _fresh(rig, what))
        # The last good frame went out at most one period before the freeze: the timeout after it
        # bounds the detection, whatever the phase (plus the 1 ms cycle).
        assert took <= timeout_s + 0.002, (sender, took)
        rig.run(0.3)
        assert not _fresh(rig, what)  # and it stays caught while the sender repeats itself
        assert rig.state is EcuState.SAFE_STOP
        assert t_freeze > 0.0
    finally:
        rig.close()


def test_the_stuck_radio_hides_a_pause_only_until_its_timeout(rig: Rig) -> None:
    rig.engaged()
    rig.stuck.add("ESTOP_Radio")
    rig.run(0.02)
    rig.estop = EstopMode.PAUSE  # pressed on a transmitter that no longer sends anything new
    took = rig.run(1.0, until=lambda: rig.state is not EcuState.ENGAGED)
    assert took <= 0.5 and rig.state is EcuState.SAFE_STOP and _fault_bits(rig) & Fault.ESTOP_TIMEOUT


# --- an exception inside a cycle -------------------------------------------------------------------


def test_an_exception_in_a_cycle_is_a_stop_fault_and_the_process_lives(
    rig: Rig, monkeypatch: pytest.MonkeyPatch
) -> None:
    rig.engaged()
    rig.run(0.3)
    calls = {"n": 0}

    def exploding_core(*args: Any) -> Any:
        calls["n"] += 1
        if calls["n"] == 1:
            raise ZeroDivisionError("a bug in the core")
        return core_step(*args)

    monkeypatch.setattr(app_module, "core_step", exploding_core)
    n_cmd = len(rig.commands)
    rig.run(0.05)
    assert rig.ecu.cycle_exceptions == 1 and "ZeroDivisionError" in (rig.ecu.last_exception or "")
    assert rig.state is EcuState.SAFE_STOP and _fault_bits(rig) & Fault.INTERNAL_ERROR
    # The cycle that raised still told the gateway to stop: the guard's safe stop command.
    _, first = rig.commands[n_cmd]
    assert first.engage and first.throttle_pct == 0.0 and first.ecu_state is EcuState.SAFE_STOP


def test_a_core_that_always_raises_brakes_to_the_hold_and_never_accelerates(
    rig: Rig, monkeypatch: pytest.MonkeyPatch
) -> None:
    rig.engaged()

    def broken(*args: Any) -> Any:
        raise IndexError("map lookup out of range")

    monkeypatch.setattr(app_module, "core_step", broken)
    n_cmd = len(rig.commands)
    rig.run(1.0)
    sent = [c for _, c in rig.commands[n_cmd:]]
    assert len(sent) >= 90 and all(c.engage and c.throttle_pct == 0.0 for c in sent)
    assert sent[-1].brake_bar == rig.cal.hold_brake_bar  # type: ignore[union-attr]
    assert rig.ecu.cycle_exceptions >= 900
    status = rig.host.latest_status()
    assert status is not None  # the node still talks: the host hears about it
    assert rig.ecu.internal_fault_events == rig.ecu.cycle_exceptions


# --- the transmit guard in the application -----------------------------------------------------------


def test_the_guard_replaces_a_broken_command_and_stops_the_car(
    rig: Rig, monkeypatch: pytest.MonkeyPatch
) -> None:
    rig.engaged()
    rig.host_silent = False

    def throttle_in_stops(*args: Any) -> Any:
        st_, cmd = core_step(*args)
        if cmd.state is not EcuState.ENGAGED:
            cmd = cmd._replace(throttle_pct=40.0, brake_bar=0.0)  # a broken stop branch
        return st_, cmd

    monkeypatch.setattr(app_module, "core_step", throttle_in_stops)
    n_cmd = len(rig.commands)
    rig.estop = EstopMode.PAUSE
    rig.run(1.0)
    sent = [c for _, c in rig.commands[n_cmd:]]
    assert all(c.throttle_pct == 0.0 for c in sent[1:])  # nothing the broken branch said went out
    assert rig.ecu.guard.trips > 0 and "propulsion only while ENGAGED" in (rig.ecu.guard.last_reason or "")
    assert rig.state is EcuState.SAFE_STOP and _fault_bits(rig) & Fault.TX_GUARD


# --- only a human re-arms ------------------------------------------------------------------------------


def test_the_service_unlatch_is_refused_with_a_true_reason(rig: Rig) -> None:
    rig.engaged()
    with pytest.raises(EcuRefusedError, match="nothing to unlatch: the ECU is ENGAGED") as err:
        rig.host.unlatch(idle=rig.tick)
    assert err.value.abort_code == ABORT_DEVICE_STATE
    rig.estop = EstopMode.DISABLE
    rig.run(0.2)
    with pytest.raises(EcuRefusedError, match="still says DISABLE"):
        rig.host.unlatch(idle=rig.tick)
    assert "still says DISABLE" in rig.host.last_refusal(idle=rig.tick)
    rig.estop = EstopMode.RUN
    rig.stuck.add("ESTOP_Radio")  # the radio repeats itself: not heard
    rig.run(0.6)
    with pytest.raises(EcuRefusedError, match="not heard"):
        rig.host.unlatch(idle=rig.tick)
    rig.stuck.clear()
    rig.run(0.1)
    rig.host.unlatch(idle=rig.tick)  # accepted: the radio is heard saying RUN
    rig.run(0.3)
    assert rig.state is EcuState.DISABLED


def test_after_a_driver_override_only_the_arm_button_and_a_new_press_engage(rig: Rig) -> None:
    rig.engaged()
    rig.driver_brake = True
    rig.run(0.1)
    rig.driver_brake = False
    rig.flags = ENGAGE | RequestFlags.REARM
    rig.run(0.1)
    rig.flags = ENGAGE
    rig.run(0.5)
    assert rig.state is EcuState.MANUAL  # the host's REARM is not a human act
    rig.arm = True
    rig.run(0.05)
    rig.arm = False
    rig.run(0.5)
    assert rig.state is EcuState.READY  # ENGAGE held as a level
    rig.press_engage()
    assert rig.state is EcuState.ENGAGED


def test_an_ecu_reset_while_the_host_holds_engage_engages_nothing(rig: Rig) -> None:
    rig.engaged()
    rig.run(0.2)
    rig.ecu = rig.new_ecu()  # power cycle / watchdog reset of the ECU
    rig.run(1.0)
    assert rig.state is EcuState.READY
    rig.press_engage()
    assert rig.state is EcuState.ENGAGED


@pytest.mark.parametrize("command", [NmtCommand.RESET_COMMUNICATION, NmtCommand.RESET_NODE])
def test_an_nmt_restart_with_engage_held_never_re_engages_on_the_level(rig: Rig, command: NmtCommand) -> None:
    rig.engaged()
    rig.speed_mps = 0.0
    rig.host.send_nmt(command)  # the host's rig restarts the node (EcuRx would too)
    rig.run(2.0)
    assert rig.state is EcuState.SAFE_STOP  # the request went away with the restart
    rig.run(1.0)
    assert rig.state is EcuState.SAFE_STOP  # ENGAGE held all along: no re-engagement
    rig.flags = ENGAGE | RequestFlags.REARM  # the host's explicit act from the hold
    rig.run(0.1)
    assert rig.state is EcuState.ENGAGED


def test_rearm_from_a_safe_stop_never_sends_a_released_command(rig: Rig) -> None:
    rig.engaged()
    rig.speed_mps = 0.0
    rig.flags = RELEASED  # the host lets go: SAFE_STOP
    rig.run(1.0)
    assert rig.state is EcuState.SAFE_STOP
    n_cmd = len(rig.commands)
    rig.flags = ENGAGE | RequestFlags.REARM
    rig.run(0.2)
    rig.flags = ENGAGE
    rig.run(0.2)
    assert rig.state is EcuState.ENGAGED
    sent = [c for _, c in rig.commands[n_cmd:]]
    assert all(c.engage for c in sent)  # no passive READY frame between the hold and driving
    held = [c for c in sent if c.ecu_state is EcuState.ENGAGED][:5]
    assert all(c.brake_bar > 0.0 for c in held)  # the brake stays on while the target rises


# --- watchdog times: bounded by the firmware, fixed while actuating --------------------------------


BOUNDED = [
    (0x1016, 1, 4, "consumer heartbeat time", lambda ms: 0x00010000 | ms, MAX_HOST_HEARTBEAT_TIMEOUT_MS),
    (0x1017, 0, 2, "producer heartbeat time", lambda ms: ms, MAX_PRODUCER_HEARTBEAT_MS),
    (0x1400, 5, 2, "request deadline", lambda ms: ms, MAX_REQUEST_DEADLINE_MS),
    (0x1800, 5, 2, "TPDO event timer", lambda ms: ms, MAX_TPDO_EVENT_TIMER_MS),
    (0x1801, 5, 2, "TPDO event timer", lambda ms: ms, MAX_TPDO_EVENT_TIMER_MS),
    (0x1802, 5, 2, "TPDO event timer", lambda ms: ms, MAX_TPDO_EVENT_TIMER_MS),
]


def test_the_eds_states_the_firmware_bounds() -> None:
    od = load_ecu_od()
    for index, sub, _, _, word, bound in BOUNDED:
        var = od[index] if sub == 0 and index == 0x1017 else od[index][sub]
        assert var.max == word(bound), hex(index)
        assert var.min == word(1), hex(index)


@pytest.mark.parametrize(("index", "sub", "size", "what", "word", "bound"), BOUNDED)
def test_watchdog_times_are_bounded_and_fixed_while_actuating(
    rig: Rig, index: int, sub: int, size: int, what: str, word: Any, bound: int
) -> None:
    rig.flags = RELEASED
    rig.run(0.3)
    assert rig.state is EcuState.READY

    def write(ms: int) -> None:
        rig.host.sdo_write(index, sub, word(ms).to_bytes(size, "little"), idle=rig.tick)

    for ms, code in (
        (bound + 1, ABORT_VALUE_TOO_HIGH),
        (0xFFFF, ABORT_VALUE_TOO_HIGH),
        (0, ABORT_VALUE_TOO_LOW),
    ):
        with pytest.raises(EcuRefusedError) as err:
            write(ms)
        assert err.value.abort_code == code, (hex(index), ms)
    write(bound)  # the bound itself is allowed while READY
    write(max(1, bound // 2))
    rig.press_engage()
    assert rig.state is EcuState.ENGAGED
    with pytest.raises(EcuRefusedError, match="while the ECU actuates") as err:
        write(max(1, bound // 3))
    assert err.value.abort_code == ABORT_DEVICE_STATE


def test_a_hung_control_loop_is_caught_within_the_bounded_deadline(rig: Rig) -> None:
    """The critical finding, replayed: the host widens its own request deadline, then its control
    loop hangs while its heartbeat goes on. The deadline cannot pass 200 ms (nor change while
    engaged), so the ECU stops the car within it."""
    rig.flags = RELEASED
    rig.run(0.3)
    with pytest.raises(EcuRefusedError):
        rig.host.sdo_write(0x1400, 5, (65535).to_bytes(2, "little"), idle=rig.tick)
    rig.host.sdo_write(0x1400, 5, MAX_REQUEST_DEADLINE_MS.to_bytes(2, "little"), idle=rig.tick)
    rig.press_engage()
    rig.accel = 2.0
    rig.run(0.5)
    rig.request_stuck = True  # the control loop hangs: the same request frame, over and over
    took = rig.run(2.0, until=lambda: rig.state is not EcuState.ENGAGED)
    assert rig.state is EcuState.SAFE_STOP and took <= MAX_REQUEST_DEADLINE_MS / 1000.0 + 0.002


# --- a foreign CANopen master (the canopen library, the shipped EDS) in every state -----------------


def _states_setups() -> dict[str, dict[str, Any]]:
    return {
        "OFF": {"calibration": None},
        "READY": {},
        "ENGAGED": {"engage": True},
        "PAUSED": {"engage": True, "estop": EstopMode.PAUSE},
        "SAFE_STOP": {"engage": True, "host_flags": RELEASED},
        "DISABLED": {"engage": True, "estop": EstopMode.DISABLE},
        "MANUAL": {"engage": True, "driver_brake": True},
    }


# (index, subindex, data, acceptable abort codes) - every writable entry, out of range.
OUT_OF_RANGE: list[tuple[int, int, bytes, set[int]]] = [
    (0x1016, 1, (0x000100C9).to_bytes(4, "little"), {ABORT_VALUE_TOO_HIGH}),
    (0x1016, 1, (0x0001FFFF).to_bytes(4, "little"), {ABORT_VALUE_TOO_HIGH}),
    (0x1016, 1, (0x00010000).to_bytes(4, "little"), {ABORT_VALUE_TOO_LOW}),
    (0x1016, 1, (0x00020064).to_bytes(4, "little"), {ABORT_VALUE_RANGE}),
    (0x1016, 1, b"\x64\x00", {0x06070010}),  # wrong length
    (0x1017, 0, (51).to_bytes(2, "little"), {ABORT_VALUE_TOO_HIGH}),
    (0x1017, 0, (0).to_bytes(2, "little"), {ABORT_VALUE_TOO_LOW}),
    (0x1400, 5, (65535).to_bytes(2, "little"), {ABORT_VALUE_TOO_HIGH}),
    (0x1400, 5, (201).to_bytes(2, "little"), {ABORT_VALUE_TOO_HIGH}),
    (0x1400, 5, (0).to_bytes(2, "little"), {ABORT_VALUE_TOO_LOW}),
    (0x1800, 5, (101).to_bytes(2, "little"), {ABORT_VALUE_TOO_HIGH}),
    (0x1801, 5, (0).to_bytes(2, "little"), {ABORT_VALUE_TOO_LOW}),
    (0x1802, 5, (65535).to_bytes(2, "little"), {ABORT_VALUE_TOO_HIGH}),
    (0x2000, 1, (100).to_bytes(2, "little", signed=True), {ABORT_LOCAL_CONTROL}),
    (0x2000, 3, b"\x01", {ABORT_LOCAL_CONTROL}),
    (0x2000, 4, b"\x07", {ABORT_LOCAL_CONTROL}),
    (0x2200, 3, b"{not a calibration", {0x08000020, ABORT_DEVICE_STATE}),
    (0x2300, 1, b"\x02", {ABORT_VALUE_RANGE}),
]


@pytest.mark.parametrize("state", sorted(_states_setups()))
def test_a_foreign_master_is_refused_every_out_of_range_write_in_every_state(state: str) -> None:
    setup = _states_setups()[state]
    with WallRig(calibration=setup.get("calibration", "default")) as rig:
        if setup.get("engage"):
            rig.engage()
        else:
            rig.flags = RELEASED
        rig.estop = setup.get("estop", EstopMode.RUN)
        rig.driver_brake = setup.get("driver_brake", False)
        if "host_flags" in setup:
            rig.flags = setup["host_flags"]
        assert rig.wait_for(lambda: rig.state is EcuState[state], 10.0), rig.state
        bus = can.Bus(interface="virtual", channel=rig.link_ch, receive_own_messages=False)
        network = canopen.Network(bus)
        network.connect_timeout = 1.0
        try:
            network.notifier = can.Notifier(bus, network.listeners, 0.1)
            node = canopen.RemoteNode(0x10, str(EDS_PATH))
            network.add_node(node)
            node.sdo.RESPONSE_TIMEOUT = 1.0
            deadline_before = rig.ecu.node.request_deadline_ms
            for index, sub, data, codes in OUT_OF_RANGE:
                with pytest.raises(SdoAbortedError) as err:
                    node.sdo.download(index, sub, data)
                assert err.value.code in codes, (state, hex(index), sub, data.hex(), hex(err.value.code))
            assert rig.ecu.node.request_deadline_ms == deadline_before
            # The unlatch in a state it does not apply to: refused for the state, with the reason.
            if state != "DISABLED":
                with pytest.raises(SdoAbortedError) as err:
                    node.sdo.download(0x2300, 1, b"\x01")
                assert err.value.code == ABORT_DEVICE_STATE
                reason = node.sdo.upload(0x2400, 0).decode("ascii")
                assert "nothing to unlatch" in reason
            # A valid time while actuating: refused for the state, never for the value.
            if state in ("ENGAGED", "PAUSED", "SAFE_STOP", "DISABLED"):
                with pytest.raises(SdoAbortedError) as err:
                    node.sdo.download(0x1400, 5, (150).to_bytes(2, "little"))
                assert err.value.code == ABORT_DEVICE_STATE
            else:
                node.sdo.download(0x1400, 5, (150).to_bytes(2, "little"))
                assert rig.ecu.node.request_deadline_ms == 150
        finally:
            network.notifier.stop()
            bus.shutdown()


# --- inputs judged by when they arrived ------------------------------------------------------------


def test_frames_queued_during_a_stall_are_judged_by_when_they_arrived(rig: Rig) -> None:
    rig.engaged()
    rig.stalled = True  # the ECU freezes for 300 ms; the host talks for 150 ms of it, then dies
    rig.run(0.15)
    t_last = rig.clock.now()
    rig.host_silent = True
    rig.run(0.15)
    rig.stalled = False
    rig.run(0.001)
    now = rig.clock.now()
    node = rig.ecu.node
    # The heartbeat and the request polled now arrived 150 ms ago, and are judged so.
    assert node.host_heartbeat.last_rx_s is not None and node.host_heartbeat.last_rx_s <= t_last
    assert not node.host_alive(now) and not node.request_fresh(now)
    assert rig.state is EcuState.SAFE_STOP
    assert _fault_bits(rig) & Fault.LOOP_STALL and _fault_bits(rig) & Fault.HOST_HEARTBEAT

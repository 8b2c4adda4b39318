"""SIL's quiet ECU cycles (`hil.sil_ecu`) leave the ECU exactly as its full cycles do.

Per cycle: a run with quiet cycles and the reference run (every cycle in full) are recorded side by
side, and every state a quiet cycle reaches (the controller, the steering command, the speed
estimate), every settled quiet run (the core's whole state and its command) and every full cycle
must equal the reference's at the same millisecond. Per run: the traces and summaries are equal.
The scenarios cover driving and steering, stops, a loop stall, a service unlatch, corrupt frames
and reverse gear.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import can
import numpy as np
import pytest

from bywire.cli import main as bywire_main
from bywire.clock import SimClock
from bywire.ecu.app import EcuApp, EcuConfig
from bywire.ecu.calibration import default_calibration
from bywire.ecu.core import core_step
from bywire.hil.scenario import FaultEvent, Scenario, load_scenario
from bywire.hil.sil import run_sil
from bywire.hil.sil_ecu import PASSIVE, QuietCycleStepper, QuietRun, quiet_deadline_s, quiet_mode
from bywire.protocol.ecu_types import EcuState


def _same(a: Any, b: Any) -> bool:
    """Equal, NaN equal to NaN (a float field may legitimately hold NaN in both runs)."""
    return a == b or repr(a) == repr(b)


def _core_view(core: Any) -> tuple:
    return (core.controller, core.steer_angle_rad, core.speed_est_mps, core.speed_trusted_t_s)


def _steering(scenario: Scenario) -> Scenario:
    """The scripted host also steers (the STEER flag set throughout)."""
    # Angles off the steering report's resolution: a held command then differs from the measurement.
    return dataclasses.replace(scenario, steer_profile=((0.0, 0.0234567), (6.0, -0.0312345)))


def _vehicle_data_lost(at_s: float) -> Callable[[Scenario], Scenario]:
    """Wheel speeds and motion stop arriving for good at `at_s`: a blind stop, held at its deadline
    (about 10 s later), and the hold."""

    def change(scenario: Scenario) -> Scenario:
        lost = FaultEvent(at_s=at_s, kind="drop", frames=("GW_WheelSpeeds", "GW_Motion"))
        return dataclasses.replace(scenario, faults=(lost,), duration_s=at_s + 13.0)

    return change


# Variants of shipped scenarios, for what none of them does alone.
VARIANTS: dict[str, tuple[str, Callable[[Scenario], Scenario]]] = {
    "estop_disable+steering": ("estop_disable", _steering),
    "estop_pause+steering": ("estop_pause", _steering),
    # Three phases of the loss against the 10 ms frame and command rhythm, so that the deadline
    # falls in a millisecond that would otherwise be quiet.
    "vehicle_data_lost": ("corrupt_frames", _vehicle_data_lost(4.0)),
    "vehicle_data_lost_3ms": ("corrupt_frames", _vehicle_data_lost(4.003)),
    "vehicle_data_lost_6ms+steering": ("corrupt_frames", lambda s: _steering(_vehicle_data_lost(4.006)(s))),
}


def _scenario(name: str) -> Scenario:
    if name in VARIANTS:
        base, change = VARIANTS[name]
        return change(load_scenario(base))
    return load_scenario(name)


def _record(name: str, duration_s: float, monkeypatch: pytest.MonkeyPatch, quiet: bool) -> dict[str, Any]:
    """Run `name` for `duration_s` and record the ECU after every cycle (full, quiet, settled)."""
    full: dict[float, tuple] = {}
    advanced: dict[float, tuple | None] = {}
    settled: dict[float, tuple] = {}
    steppers: list[QuietCycleStepper] = []
    app_step = EcuApp.step
    stepper_init = QuietCycleStepper.__init__
    advance = QuietRun.advance
    settle = QuietCycleStepper.settle

    def recording_step(self: EcuApp, now_s: float) -> None:
        app_step(self, now_s)
        full[now_s] = (self.core, self.last_command)

    def recording_init(self: QuietCycleStepper, *args: Any, **kwargs: Any) -> None:
        stepper_init(self, *args, **kwargs)
        steppers.append(self)

    def recording_advance(self: QuietRun, now_s: float) -> None:
        advance(self, now_s)
        # A hands-off run keeps no intermediate state (settling recomputes it from the run's start).
        advanced[now_s] = None if self.mode == PASSIVE else _core_view(self.state())

    def recording_settle(self: QuietCycleStepper) -> None:
        pending, held = self.run is not None, self._held_t
        settle(self)
        if pending:
            settled[held] = (self.ecu.core, self.ecu.last_command)

    with monkeypatch.context() as m:
        m.setattr(EcuApp, "step", recording_step)
        m.setattr(QuietCycleStepper, "__init__", recording_init)
        m.setattr(QuietRun, "advance", recording_advance)
        m.setattr(QuietCycleStepper, "settle", recording_settle)
        scenario = _scenario(name)
        scenario = dataclasses.replace(scenario, duration_s=min(duration_s, scenario.duration_s))
        result = run_sil(scenario, quiet_ecu=quiet)
    return {
        "full": full,
        "advanced": advanced,
        "settled": settled,
        "stepper": steppers[-1],
        "result": result,
    }


# (scenario, seconds): driving with steering; the stops (E-stop pause and resume, DISABLE and its
# hold with the ignition off, the driver's brake and the MANUAL after it, heartbeat loss, a frozen
# host, corrupt and stale frames: blind stops); a loop stall; the service unlatch after a DISABLE;
# no valid calibration (OFF); a K-turn (reverse gear, shifts); and the variants above (stops
# while steering, which a DISABLE releases at its hold; vehicle data lost: blind stops).
CASES = [
    *((name, 17.0 if "lost" in name else 12.0) for name in VARIANTS),
    ("demo", 20.0),
    ("estop_pause", 12.0),
    ("estop_disable", 12.0),
    ("driver_brake", 12.0),
    ("driver_override_rearm", 20.0),
    ("heartbeat_loss", 12.0),
    ("host_freeze", 12.0),
    ("corrupt_frames", 10.0),
    ("stale_frames", 10.0),
    ("loop_stall", 8.0),
    ("unlatch_with_engage_held", 20.0),
    ("bad_calibration", 5.0),
    ("kturn_narrow_road", 40.0),
]


@pytest.mark.parametrize(("name", "duration_s"), CASES, ids=[c[0] for c in CASES])
def test_quiet_cycles_leave_the_ecu_as_full_cycles_do(
    name: str, duration_s: float, monkeypatch: pytest.MonkeyPatch
) -> None:
    ref = _record(name, duration_s, monkeypatch, quiet=False)
    fast = _record(name, duration_s, monkeypatch, quiet=True)
    reference = ref["full"]
    assert ref["stepper"].quiet_cycles == 0 and not ref["advanced"]
    stepper = fast["stepper"]
    # The fast path is exercised (ENGAGED driving; the stops run in full), and every millisecond is
    # one kind of cycle or another.
    assert stepper.quiet_cycles > 1000, (stepper.quiet_cycles, stepper.full_cycles)
    assert stepper.quiet_cycles + stepper.full_cycles == len(reference)
    assert len(fast["advanced"]) + len(fast["settled"]) == stepper.quiet_cycles
    for t, (core, cmd) in fast["full"].items():
        ref_core, ref_cmd = reference[t]
        assert _same(core, ref_core) and core.verdict == ref_core.verdict, f"full cycle at {t} s"
        assert _same(cmd, ref_cmd), f"full cycle at {t} s"
    for t, view in fast["advanced"].items():
        assert view is None or _same(view, _core_view(reference[t][0])), f"quiet cycle at {t} s"
    for t, (core, cmd) in fast["settled"].items():
        ref_core, ref_cmd = reference[t]
        assert _same(core, ref_core), f"settled quiet run at {t} s"
        assert _same(cmd, ref_cmd), f"settled quiet run at {t} s"
    for key in ("plant", "host", "traffic"):
        a, b = getattr(ref["result"], key) or {}, getattr(fast["result"], key) or {}
        assert a.keys() == b.keys()
        for col in a:
            assert np.array_equal(a[col], b[col], equal_nan=True), f"{key}.{col}"
    # The summaries but what is measured on the wall clock (the factor, the host modules' run times).
    wall = ("real_time_factor", "host_runtime")
    extra_ref = {k: v for k, v in ref["result"].extra.items() if k not in wall}
    extra_fast = {k: v for k, v in fast["result"].extra.items() if k not in wall}
    assert repr(extra_ref) == repr(extra_fast)


@pytest.mark.parametrize(
    ("name", "duration_s", "states"),
    [
        ("estop_pause", 12.0, {"READY", "ENGAGED", "PAUSED"}),
        ("estop_disable", 12.0, {"READY", "ENGAGED", "DISABLED"}),
        ("corrupt_frames", 10.0, {"READY", "ENGAGED", "SAFE_STOP"}),
        ("bad_calibration", 5.0, {"OFF"}),
        ("vehicle_data_lost", 17.0, {"READY", "ENGAGED", "SAFE_STOP"}),
    ],
)
def test_every_kind_of_state_has_quiet_runs(
    name: str, duration_s: float, states: set[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Driving, stopping (seeing and blind) and hands-off states all run quiet cycles, not only driving."""
    fast = _record(name, duration_s, monkeypatch, quiet=True)
    settled = {core.safety.state.name for core, _ in fast["settled"].values()}
    assert states <= settled, settled


def test_a_bus_other_than_sils_runs_every_cycle_in_full() -> None:
    """The checks read SIL's bus queues; on any other bus the stepper is the plain `ecu.step`."""
    channel = "quiet-ecu-plain-virtual"
    clock = SimClock(0.0)
    buses = [can.Bus(interface="virtual", channel=f"{channel}-{i}") for i in range(2)]
    try:
        ecu = EcuApp(buses[0], buses[1], clock, default_calibration(), None, EcuConfig())
        stepper = QuietCycleStepper(ecu)
        assert not stepper.enabled
        for k in range(50):
            clock.advance_to(k * 1e-3)
            stepper.step(k * 1e-3)
        assert stepper.full_cycles == 50 and stepper.quiet_cycles == 0
        assert math.isclose(ecu.core.controller.t_s, 0.049)
    finally:
        for b in buses:
            b.shutdown()


def test_a_quiet_run_ends_before_every_deadline_of_the_ecu(monkeypatch: pytest.MonkeyPatch) -> None:
    """A quiet run never reaches the next DBW_Command, status TPDO, node timer or expiry of the
    inputs, each on its own (in the scenarios several often coincide, and would hide one missing)."""
    starts = []
    may_start = QuietCycleStepper._run_may_start

    def checked(self: QuietCycleStepper, now_s: float) -> bool:
        ok = may_start(self, now_s)
        if ok:
            ecu = self.ecu
            assert now_s < self._run_until
            assert self._run_until <= ecu._next_command_s
            assert self._run_until <= ecu._next_status_s
            assert self._run_until <= ecu.node._quiet_until_s
            assert self._run_until <= quiet_deadline_s(ecu.core)
            assert (
                ecu._inputs_valid_until_s
                < self._run_until
                <= math.nextafter(ecu._inputs_valid_until_s, math.inf)
                or self._run_until < ecu._inputs_valid_until_s
            )
            starts.append(now_s)
        return ok

    monkeypatch.setattr(QuietCycleStepper, "_run_may_start", checked)
    run_sil(dataclasses.replace(load_scenario("demo"), duration_s=5.0))
    run_sil(_scenario("vehicle_data_lost"))  # a blind stop: its deadline binds
    assert len(starts) > 100


def _stepper_after(name: str, duration_s: float, monkeypatch: pytest.MonkeyPatch) -> QuietCycleStepper:
    """The stepper of a run of `name` after `duration_s`, its ECU's deadlines moved a second ahead,
    so that the next cycle is quiet unless something else says otherwise."""
    steppers: list[QuietCycleStepper] = []
    init = QuietCycleStepper.__init__

    def keep(self: QuietCycleStepper, *args: Any, **kwargs: Any) -> None:
        init(self, *args, **kwargs)
        steppers.append(self)

    with monkeypatch.context() as m:
        m.setattr(QuietCycleStepper, "__init__", keep)
        run_sil(dataclasses.replace(load_scenario(name), duration_s=duration_s))
    stepper = steppers[-1]
    ecu = stepper.ecu
    assert ecu._last_cycle_s is not None
    t = ecu._last_cycle_s + 1e-3
    ecu._next_command_s = ecu._next_status_s = ecu.node._quiet_until_s = t + 1.0
    ecu._inputs_valid_until_s = t + 1.0
    return stepper


def test_what_makes_the_ecu_recompute_its_inputs_ends_quiet_cycles(monkeypatch: pytest.MonkeyPatch) -> None:
    """`EcuApp._cycle` recomputes its inputs after an event it judges once (a loop stall, an unlatch,
    an exception, a guard trip: pending, or judged last cycle), when the executive's overrun streak
    moved, and a frame since the node's last full tick means work for it: none of those cycles is
    quiet, nor one whose faults differ from those reported."""
    stepper = _stepper_after("demo", 3.0, monkeypatch)
    ecu = stepper.ecu
    t = ecu._last_cycle_s + 1e-3  # type: ignore[operator]
    assert stepper._run_may_start(t), "the reference point is quiet"
    for pending in ("_unlatch_pending", "_stall_pending", "_internal_pending", "_guard_pending"):
        setattr(ecu, pending, True)
        assert not stepper._run_may_start(t), pending
        setattr(ecu, pending, False)
    ecu.stats.overrun_streak += 1
    assert not stepper._run_may_start(t), "overrun streak"
    ecu.stats.overrun_streak -= 1
    ecu.node._rx_frames += 1
    assert not stepper._run_may_start(t), "a frame since the node's last full tick"
    ecu.node._rx_frames -= 1
    ecu._reported_faults ^= 1
    assert not stepper._run_may_start(t), "faults reported"
    ecu._reported_faults ^= 1
    assert stepper._run_may_start(t)


@pytest.mark.parametrize("flag", ["unlatch", "loop_stall", "internal_error", "tx_guard_trip"])
def test_inputs_with_an_event_judged_once_are_not_reused(flag: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """In a latched stop the event's fault changes nothing the state machine does, but the next
    cycle's inputs are recomputed without it (its active faults, and so the command, change)."""
    stepper = _stepper_after("loop_stall", 7.0, monkeypatch)
    ecu = stepper.ecu
    t = ecu._last_cycle_s + 1e-3  # type: ignore[operator]
    assert ecu.core.safety.state is EcuState.SAFE_STOP
    assert stepper._run_may_start(t), "the reference point is quiet"
    assert ecu._last_inputs is not None
    event: dict[str, Any] = {flag: True}
    inputs = dataclasses.replace(ecu._last_inputs, **event)
    ecu._last_inputs = inputs
    # The last cycle again, as if it had judged the event: the state and faults it leaves.
    ecu.core, cmd = core_step(ecu.core, inputs, t - 1e-3, ecu._core_cal)
    ecu._reported_faults = int(cmd.faults_active) | int(cmd.faults_latched)
    assert quiet_mode(ecu.core, inputs, ecu._core_cal) == "stop", "the core alone would continue the stop"
    assert not stepper._run_may_start(t)


def test_the_cli_runs_every_ecu_cycle_in_full_on_request(tmp_path: Path) -> None:
    """`bywire hil run NAME --mode sil --every-ecu-cycle`: the reference, for a user who doubts the
    fast path; its verdict and every metric but the wall clock's are those of the default run."""
    docs = {}
    for label, extra in (("quiet", []), ("full", ["--every-ecu-cycle"])):
        out = tmp_path / f"{label}.json"
        argv = ["hil", "run", "estop_pause", "--mode", "sil", "--json", str(out), "--quiet", *extra]
        assert bywire_main(argv) == 0
        docs[label] = json.loads(out.read_text())
    for doc in docs.values():
        doc["metrics"].pop("real_time_factor", None)
        doc["metrics"].pop("host_runtime", None)
    assert docs["quiet"]["verdict"] == docs["full"]["verdict"] == "pass"
    assert docs["quiet"]["metrics"] == docs["full"]["metrics"]

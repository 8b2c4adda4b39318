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
import math
from typing import Any

import can
import numpy as np
import pytest

from bywire.clock import SimClock
from bywire.ecu.app import EcuApp, EcuConfig
from bywire.ecu.calibration import default_calibration
from bywire.hil.scenario import load_scenario
from bywire.hil.sil import run_sil
from bywire.hil.sil_ecu import QuietCycleStepper


def _same(a: Any, b: Any) -> bool:
    """Equal, NaN equal to NaN (a float field may legitimately hold NaN in both runs)."""
    return a == b or repr(a) == repr(b)


def _core_view(core: Any) -> tuple:
    return (core.controller, core.steer_angle_rad, core.speed_est_mps, core.speed_trusted_t_s)


def _record(name: str, duration_s: float, monkeypatch: pytest.MonkeyPatch, quiet: bool) -> dict[str, Any]:
    """Run `name` for `duration_s` and record the ECU after every cycle (full, quiet, settled)."""
    full: dict[float, tuple] = {}
    advanced: dict[float, tuple] = {}
    settled: dict[float, tuple] = {}
    steppers: list[QuietCycleStepper] = []
    app_step = EcuApp.step
    stepper_init = QuietCycleStepper.__init__
    advance = QuietCycleStepper._advance
    settle = QuietCycleStepper.settle

    def recording_step(self: EcuApp, now_s: float) -> None:
        app_step(self, now_s)
        full[now_s] = (self.core, self.last_command)

    def recording_init(self: QuietCycleStepper, *args: Any, **kwargs: Any) -> None:
        stepper_init(self, *args, **kwargs)
        steppers.append(self)

    def recording_advance(self: QuietCycleStepper, now_s: float) -> None:
        advance(self, now_s)
        advanced[now_s] = (self._ctl, self._steer, self._v_est, self._trusted_t)

    def recording_settle(self: QuietCycleStepper) -> None:
        pending, held = self._run, self._held_t
        settle(self)
        if pending:
            settled[held] = (self.ecu.core, self.ecu.last_command)

    with monkeypatch.context() as m:
        m.setattr(EcuApp, "step", recording_step)
        m.setattr(QuietCycleStepper, "__init__", recording_init)
        m.setattr(QuietCycleStepper, "_advance", recording_advance)
        m.setattr(QuietCycleStepper, "settle", recording_settle)
        scenario = load_scenario(name)
        scenario = dataclasses.replace(scenario, duration_s=min(duration_s, scenario.duration_s))
        result = run_sil(scenario, quiet_ecu=quiet)
    return {
        "full": full,
        "advanced": advanced,
        "settled": settled,
        "stepper": steppers[-1],
        "result": result,
    }


# (scenario, seconds): driving with steering, an E-stop pause and its resume, a loop stall, the
# service unlatch after a DISABLE, corrupt frames, and a K-turn (reverse gear, shifts).
CASES = [
    ("demo", 20.0),
    ("estop_pause", 12.0),
    ("loop_stall", 8.0),
    ("unlatch_with_engage_held", 20.0),
    ("corrupt_frames", 10.0),
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
        assert _same(view, _core_view(reference[t][0])), f"quiet cycle at {t} s"
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


def test_the_shifting_and_stopping_cycles_are_full_cycles(monkeypatch: pytest.MonkeyPatch) -> None:
    """Only ENGAGED driving is quiet: a cycle in a stop or a shift always runs in full."""
    fast = _record("estop_pause", 12.0, monkeypatch, quiet=True)
    states = {core.safety.state.name for core, _ in fast["settled"].values()}
    assert states == {"ENGAGED"}
    stops = [t for t, (core, _) in fast["full"].items() if core.safety.state.name == "PAUSED"]
    assert stops, "the scenario pauses"


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
            assert (
                ecu._inputs_valid_until_s
                < self._run_until
                <= math.nextafter(ecu._inputs_valid_until_s, math.inf)
                or self._run_until < ecu._inputs_valid_until_s
            )
            starts.append(now_s)
        return ok

    monkeypatch.setattr(QuietCycleStepper, "_run_may_start", checked)
    scenario = dataclasses.replace(load_scenario("demo"), duration_s=5.0)
    run_sil(scenario)
    assert len(starts) > 100

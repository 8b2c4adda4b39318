"""The host agent: the spine's host as modules on the runtime (issue 3), one store, one clock.

The agent builds the runtime from a host configuration (`host.config`): the scenario's mission,
the ECU link (status in, requests and heartbeat out), odometry, radar and lead tracker, and the
longitudinal override controller of seed 000 section 11.2 (or, in the `gcdc` configuration of issue 4,
GPS, pose, V2V, world model and platoon control over the V2X link and the GPS line it is given; in the
`urban` configuration of issue 5, the behaviour and lateral/longitudinal control on the object link), each
with its rate, deadline and failure policy. In SIL the driver calls `step(now_s)` every simulated
millisecond and the runtime runs in lockstep; as a process (`bywire host run`) the runtime ticks on
the wall clock.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import can

from bywire.clock import Clock, SimClock
from bywire.hil.module_faults import ModuleFaultInjector
from bywire.hil.scenario import MODULE_FAULTS, Scenario, ScenarioError
from bywire.hil.trace import HOST_COLUMNS, TraceWriter
from bywire.host.config import HostConfig, load_host_config
from bywire.host.modules import KINDS, HostResources
from bywire.host.modules.messages import RUN_INFO, RunInfo
from bywire.host.runtime.module import Module
from bywire.host.runtime.runtime import Runtime
from bywire.host.runtime.store import ObjectStore
from bywire.protocol.canopen_link.host_master import HostMaster


class HostAgent:
    """Steppable host: call `step(now_s)` every millisecond (SIL), or `run_wall(...)` (a process)."""

    def __init__(
        self,
        scenario: Scenario,
        link: HostMaster,
        t0_s: float,
        sensor_bus: can.BusABC | None = None,
        trace: TraceWriter | None = None,
        config: HostConfig | None = None,
        clock: Clock | None = None,
        lockstep: bool = True,
        in_process_faults: bool = True,
        store: ObjectStore | None = None,
        v2x: Any = None,
        gps: Any = None,
        vehicle_bus: can.BusABC | None = None,
        unix_time: Callable[[float], float] | None = None,
        objects: Any = None,
    ) -> None:
        self.scenario = scenario
        self.t0_s = t0_s
        self.config = config or load_host_config(scenario.host_config)
        self.clock = clock or SimClock(t0_s)
        self.store = store or ObjectStore()
        self.trace = trace or TraceWriter(None, HOST_COLUMNS)
        self.resources = HostResources(
            scenario,
            t0_s,
            link,
            sensor_bus,
            self.trace,
            v2x=v2x,
            gps=gps,
            vehicle_bus=vehicle_bus,
            unix_time=unix_time,
            objects=objects,
        )
        self.resources.prepare_world(self.config.modules)
        # In HIL the runner freezes or kills the real process; in SIL the agent stops itself.
        self.in_process_faults = in_process_faults
        # The faults that stop this host in process, looked up once: `step` runs every millisecond.
        self._stop_faults = (
            tuple(f for f in scenario.faults if f.kind in ("host_freeze", "host_kill"))
            if in_process_faults
            else ()
        )
        check_module_faults(scenario, self.config)
        self.stopped = False
        process_worker = None
        if any(m.spec.isolation == "process" for m in self.config.modules):
            from bywire.host.runtime.process_worker import process_worker_maker

            process_worker = process_worker_maker(lockstep=lockstep)
        if not lockstep:
            # A module stuck in a pure-Python loop holds the GIL; the scheduler thread gets it back
            # only at the interpreter's switch interval (5 ms by default), once per blocking call.
            # 0.5 ms keeps the supervisor's own timing within its bounds while the culprit spins.
            sys.setswitchinterval(0.0005)
        self.injector = ModuleFaultInjector(scenario, t0_s)
        self.runtime = Runtime(
            self.store,
            self.clock,
            lockstep=lockstep,
            injector=self.injector,
            health_period_s=self.config.health_period_s,
            process_worker=process_worker,
        )
        for m in self.config.modules:
            self.runtime.add_module(m.spec, self._factory(m.kind, m.params), {"kind": m.kind, **m.params})
        self._started = False

    def _factory(self, kind: str, params: dict[str, Any]) -> Callable[[], Module]:
        build = KINDS[kind].build
        resources = self.resources
        return lambda: build(params, resources)

    def prestart(self) -> bool:
        """Start the worker processes before the run (see `Runtime.prestart`)."""
        return self.runtime.prestart()

    def set_t0(self, t0_s: float) -> None:
        """The run's start instant, when it is known only after `prestart` (a HIL start handshake)."""
        if self._started:
            raise RuntimeError("t0 is fixed once the host runs")
        self.t0_s = self.resources.t0_s = self.injector.t0_s = t0_s

    def _stopped_by_fault(self, t: float) -> bool:
        return any(f.active(t) for f in self._stop_faults)

    def step(self, now_s: float) -> None:
        if self.stopped:
            return
        t = now_s - self.t0_s
        if self._stop_faults and self._stopped_by_fault(t):
            self.stopped = True  # SIL's stand-in for SIGSTOP / SIGKILL of the host process
            return
        if not self._started:
            self._start(now_s)
        self.runtime.tick(now_s)

    def run_wall(self, until_s: float, stop: Callable[[], bool]) -> None:
        self._start(self.clock.now())
        self.runtime.run_wall(until_s, stop, self.config.tick_s)

    def _start(self, now_s: float) -> None:
        # First on the record: what a replay needs to rebuild this host (scenario and configuration).
        self.store.publish(
            RUN_INFO,
            RunInfo(
                t_s=now_s,
                scenario_source=self.scenario.source,
                scenario_text=_read_text(self.scenario.source),
                host_config_source=self.config.source,
                host_config_json=json.dumps(self.config.data, sort_keys=True),
                lockstep=self.runtime.lockstep,
            ),
        )
        self.runtime.start(now_s)
        self._started = True

    def summary(self) -> dict[str, Any]:
        return self.runtime.summary()

    def gcdc_summary(self) -> dict[str, Any]:
        """What the cooperative modules counted (issue 4): V2V received / accepted / rejected by reason,
        our CAMs sent, the pose server's dropped sentences and frozen fixes. Empty without them."""
        from bywire.host.modules.gcdc_messages import POSE, V2V_RECEIVED, V2V_SENT

        out: dict[str, Any] = {}
        batch = self.store.latest(V2V_RECEIVED)
        if batch is not None:
            out["v2v_received"] = batch.received
            out["v2v_accepted"] = batch.accepted
            out["v2v_rejected"] = {rc.reason: rc.count for rc in batch.rejected}
        cam = self.store.latest(V2V_SENT)
        if cam is not None:
            out["cam_sent"] = cam.count
        pose = self.store.latest(POSE)
        if pose is not None:
            out["nmea_dropped"] = pose.nmea_dropped
            out["frozen_fixes"] = pose.frozen_fixes
        return out

    def urban_summary(self) -> dict[str, Any]:
        """The urban modules' log (issue 5): the behaviour's state history, faults, the checkpoints it
        counted, backward legs held. Empty without them."""
        if not self.config.uses("urban_io", "urban_behaviour", "urban_control"):
            return {}
        out: dict[str, Any] = self.resources.urban_log().summary()
        out["t0_s"] = self.t0_s  # the state history's times are on the runtime clock
        return out

    def close(self) -> None:
        if self._started:
            self.runtime.close()


def check_module_faults(scenario: Scenario, config: HostConfig) -> None:
    """A module fault that names no module of this host would silently do nothing: refuse it."""
    modules = {m.spec.name: m for m in config.modules}
    for i, f in enumerate(scenario.faults):
        if f.kind not in MODULE_FAULTS:
            continue
        if f.module not in modules:
            raise ScenarioError(
                scenario.source,
                f"faults[{i}].module",
                f"no module {f.module!r} in host configuration {config.source} ({', '.join(modules)})",
            )
        isolated = modules[f.module].spec.isolation == "process"
        if f.kind == "module_kill" and not isolated:
            raise ScenarioError(
                scenario.source,
                f"faults[{i}].kind",
                f"{f.module} runs in a thread of the host: only a worker process can be killed",
            )
        if f.kind != "module_kill" and isolated:
            raise ScenarioError(
                scenario.source,
                f"faults[{i}].kind",
                f"{f.kind} is injected into thread workers; {f.module} runs in a process",
            )


def _read_text(path: str) -> str:
    try:
        return Path(path).read_text(encoding="utf-8")
    except OSError:
        return ""  # a scenario built in memory: the recording cannot carry it

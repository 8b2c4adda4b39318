"""The host agent: the spine's host as modules on the runtime, one store, one clock.

The agent builds the runtime from a host configuration (`host.config`): the driver's commands,
the ECU link (status in, requests and heartbeat out), odometry, radar and lead tracker, and the
longitudinal override controller of seed 000 section 11.2 (or, in the `gcdc` configuration of seed 003,
GPS, pose, V2V, world model and platoon control over the V2X link and the GPS line it is given; in the
`urban` configuration of seed 000, the behaviour and lateral/longitudinal control on the object link), each
with its rate, deadline and failure policy. In SIL the driver calls `step(now_s)` every simulated
millisecond and the runtime runs in lockstep; as a process (`bywire host run`) the runtime ticks on
the wall clock.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable
from typing import Any

import can

from bywire.clock import Clock, SimClock
from bywire.host.config import HostConfig
from bywire.host.inputs import HostFaultHooks, HostInputs, NoFaults
from bywire.host.modules import KINDS, HostResources, import_implementations
from bywire.host.modules.gcdc_messages import V2V_ICLCM_SENT, V2V_SENT
from bywire.host.modules.messages import RUN_INFO, RunInfo
from bywire.host.runtime.module import Module
from bywire.host.runtime.runtime import Runtime
from bywire.host.runtime.store import ObjectStore
from bywire.host.trace import HOST_COLUMNS, TraceWriter
from bywire.protocol.canopen_link.host_master import HostMaster


class HostAgent:
    """Steppable host: call `step(now_s)` every millisecond (SIL), or `run_wall(...)` (a process)."""

    def __init__(
        self,
        inputs: HostInputs,
        link: HostMaster,
        t0_s: float,
        config: HostConfig,
        sensor_bus: can.BusABC | None = None,
        trace: TraceWriter | None = None,
        clock: Clock | None = None,
        lockstep: bool = True,
        faults: HostFaultHooks | None = None,
        store: ObjectStore | None = None,
        v2x: Any = None,
        gps: Any = None,
        vehicle_bus: can.BusABC | None = None,
        unix_time: Callable[[float], float] | None = None,
        objects: Any = None,
        scans: Any = None,
        heartbeat_sent: Callable[[float], None] | None = None,
    ) -> None:
        self.inputs = inputs
        self.t0_s = t0_s
        self.config = config
        self.faults: HostFaultHooks = faults if faults is not None else NoFaults()
        self.clock = clock or SimClock(t0_s)
        self.store = store or ObjectStore()
        self.trace = trace or TraceWriter(None, HOST_COLUMNS)
        self.resources = HostResources(
            inputs,
            t0_s,
            link,
            sensor_bus,
            self.trace,
            v2x=v2x,
            gps=gps,
            vehicle_bus=vehicle_bus,
            unix_time=unix_time,
            objects=objects,
            scans=scans,
            faults=self.faults,
            heartbeat_sent=heartbeat_sent,
            lockstep=lockstep,
        )
        self.resources.prepare_world(self.config.modules)
        self.stopped = False
        process_worker = None
        if any(m.spec.isolation == "process" for m in self.config.modules):
            from bywire.host.modules import build_isolated
            from bywire.host.runtime.process_worker import process_worker_maker

            process_worker = process_worker_maker(lockstep=lockstep, build=build_isolated)
        if not lockstep:
            # A module stuck in a pure-Python loop holds the GIL; the scheduler thread gets it back
            # only at the interpreter's switch interval (5 ms by default), once per blocking call.
            # 0.5 ms keeps the supervisor's own timing within its bounds while the culprit spins.
            sys.setswitchinterval(0.0005)
        self.faults.t0_s = t0_s
        self.runtime = Runtime(
            self.store,
            self.clock,
            lockstep=lockstep,
            injector=self.faults,
            health_period_s=self.config.health_period_s,
            process_worker=process_worker,
        )
        for m in self.config.modules:
            self.runtime.add_module(m.spec, self._factory(m.kind, m.params), {"kind": m.kind, **m.params})
        self._started = False
        # our V2V messages sent over every instance of the sender: a restarted one counts from 0
        self._v2v_sent = {V2V_SENT: 0, V2V_ICLCM_SENT: 0}
        self.store.add_tap(self._count_v2v_sent)

    def _count_v2v_sent(self, topic: str, obj: Any) -> None:
        if topic in self._v2v_sent and obj.sent:
            self._v2v_sent[topic] += 1  # the sender's thread is its topic's only publisher

    def _factory(self, kind: str, params: dict[str, Any]) -> Callable[[], Module]:
        build = KINDS[kind].build
        resources = self.resources

        def make() -> Module:
            module = build(params, resources)
            # On the module's own thread (the factory runs there): pyproj keeps a transformer per
            # thread and builds it at its first use in that thread, 100 ms holding the GIL.
            resources.warm_up()
            return module

        return make

    def prestart(self) -> bool:
        """Before the run: import what the modules' builders import and start the worker processes
        (see `Runtime.prestart`), so that neither lands in the first cycles of driving."""
        import_implementations(m.kind for m in self.config.modules)
        self.resources.warm_up()
        return self.runtime.prestart()

    def set_t0(self, t0_s: float) -> None:
        """The run's start instant, when it is known only after `prestart` (a HIL start handshake)."""
        if self._started:
            raise RuntimeError("t0 is fixed once the host runs")
        self.t0_s = self.resources.t0_s = self.faults.t0_s = t0_s

    def step(self, now_s: float) -> None:
        if self.stopped:
            return
        if self.faults.host_stopped(now_s):
            self.stopped = True  # SIL's stand-in for SIGSTOP / SIGKILL of the host process
            return
        if not self._started:
            self._start(now_s)
        self.runtime.tick(now_s)

    def run_wall(
        self, until_s: float, stop: Callable[[], bool], beat: Callable[[float], None] | None = None
    ) -> None:
        # The run's grid starts at t0, the instant every process of the run shares (the runner's, or
        # the car's start): the runtime's times (`t_rel_s` of its events) and the faults injected at
        # t0 + at_s then count from the same zero, however late this thread got here.
        self._start(min(self.t0_s, self.clock.now()))
        self.runtime.run_wall(until_s, stop, self.config.tick_s, beat)

    def _start(self, now_s: float) -> None:
        # First on the record: what a replay needs to rebuild this host (its configuration), and what
        # its mission came from.
        self.store.publish(
            RUN_INFO,
            RunInfo(
                t_s=now_s,
                scenario_source=self.inputs.source,
                scenario_text=self.inputs.source_text,
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
        """What the cooperative modules counted: V2V received / accepted / rejected by reason,
        our CAMs and iCLCMs sent (over every instance of the sender), the pose server's dropped
        sentences and frozen fixes. Empty without them."""
        from bywire.host.modules.gcdc_messages import POSE, V2V_RECEIVED

        out: dict[str, Any] = {}
        batch = self.store.latest(V2V_RECEIVED)
        if batch is not None:
            out["v2v_received"] = batch.received
            out["v2v_accepted"] = batch.accepted
            out["v2v_rejected"] = {rc.reason: rc.count for rc in batch.rejected}
        if self.store.latest(V2V_SENT) is not None:
            out["cam_sent"] = self._v2v_sent[V2V_SENT]
        if self.store.latest(V2V_ICLCM_SENT) is not None:
            out["iclcm_sent"] = self._v2v_sent[V2V_ICLCM_SENT]
        pose = self.store.latest(POSE)
        if pose is not None:
            out["nmea_dropped"] = pose.nmea_dropped
            out["frozen_fixes"] = pose.frozen_fixes
        return out

    def urban_summary(self) -> dict[str, Any]:
        """The urban modules' log: the behaviour's state history, faults, the checkpoints it
        counted, backward legs held. Empty without them."""
        if not self.config.uses("urban_io", "urban_pose", "urban_behaviour", "urban_control"):
            return {}
        out: dict[str, Any] = self.resources.urban_log().summary()
        out["t0_s"] = self.t0_s  # the state history's times are on the runtime clock
        return out

    def close(self) -> None:
        if self._started:
            self.runtime.close()

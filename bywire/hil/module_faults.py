"""Fault injection into host modules, for the scenarios of the runtime's supervisor (DESIGN section 4).

Each fault is what the supervisor must catch in the wild, made on purpose, inside the module's own
release so that nothing but the data flow and timing gives it away:

- `module_exception`: the step raises, once;
- `module_hang`: the step never returns (a busy loop, once);
- `module_deadlock`: the step blocks forever on a lock it already holds (once);
- `module_slow`: every step takes `slow_ms` longer while the fault is active (wall time: it is the
  CPU cost of the step that grows, in SIL as in HIL);
- `module_kill`: the module's worker process gets SIGKILL (from the host's scheduler thread, as an
  operator's `kill -9` would), once.

One-shot faults fire in the first release at or after `at_s`, whichever instance is running then;
a restarted instance does not fail again, as after a real transient fault.
"""

from __future__ import annotations

import os
import signal
import threading
import time
from typing import Any

from bywire.hil.scenario import MODULE_FAULTS, FaultEvent, Scenario, ScenarioError
from bywire.host.config import HostConfig


class InjectedFault(RuntimeError):
    """The exception of a `module_exception` fault."""


class ModuleFaultInjector:
    """A scenario's host-side faults, handed to the host as its `HostFaultHooks`: module faults, and,
    `in_process` (SIL), the host stopping itself where HIL freezes or kills its process."""

    def __init__(self, scenario: Scenario, t0_s: float, in_process: bool = True) -> None:
        self.faults: tuple[FaultEvent, ...] = scenario.faults_of(*MODULE_FAULTS)
        self.t0_s = t0_s
        # Looked up once: the host asks every simulated millisecond.
        self._stop_faults = scenario.faults_of("host_freeze", "host_kill") if in_process else ()
        self._mute_faults = scenario.faults_of("heartbeat_mute")
        self._kills = tuple((i, f) for i, f in enumerate(self.faults) if f.kind == "module_kill")
        self._fired: set[int] = set()
        self._lock = threading.Lock()

    def host_stopped(self, now_s: float) -> bool:
        if not self._stop_faults:
            return False  # most scenarios: no generator every simulated millisecond
        t = now_s - self.t0_s
        return any(f.active(t) for f in self._stop_faults)

    def heartbeat_muted(self, now_s: float) -> bool:
        t = now_s - self.t0_s
        return any(f.active(t) for f in self._mute_faults)

    def _take(self, i: int) -> bool:
        with self._lock:
            if i in self._fired:
                return False
            self._fired.add(i)
            return True

    def before_step(self, module: str, ctx: Any) -> None:
        t = ctx.now_s - self.t0_s
        for i, f in enumerate(self.faults):
            if f.module != module or t < f.at_s:
                continue
            if f.kind == "module_slow":
                if f.active(t):
                    time.sleep(f.slow_ms / 1e3)
            elif f.kind == "module_exception" and self._take(i):
                raise InjectedFault(f"injected at {f.at_s:g} s")
            elif f.kind == "module_hang" and self._take(i):
                while True:
                    pass
            elif f.kind == "module_deadlock" and self._take(i):
                lock = threading.Lock()
                lock.acquire()
                lock.acquire()  # never returns: the thread holds the lock it waits for

    def tick(self, runtime: Any, now_s: float) -> None:
        if not self._kills:
            return  # called every simulated millisecond; only a kill fault acts here
        t = now_s - self.t0_s
        for i, f in self._kills:
            if t < f.at_s or i in self._fired:
                continue
            entry = runtime.entries.get(f.module)
            pid = getattr(entry.worker, "pid", None) if entry is not None else None
            if pid is None:
                continue  # not started yet (or not a process worker: refused when the host is built)
            self._take(i)
            os.kill(pid, signal.SIGKILL)
            process = getattr(entry.worker, "process", None)
            if runtime.lockstep and process is not None:
                process.join(1.0)  # dead before the supervisor looks: SIL stays deterministic


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

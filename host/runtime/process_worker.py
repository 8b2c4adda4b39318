"""A module in a worker process of its own: crash-isolated, killable, supervised like a thread worker.

For modules that may crash the interpreter or hang in native code (a perception stack, say): the
module runs in a child process with its own object store, connected to the host's store through the
runtime's transport (`transport`: its inputs flow in, its outputs flow out, each on one ordered
stream). The scheduler drives it with the same release / done protocol as a thread worker, as
objects on a control topic in the same streams, so a release always reaches the child after the
inputs published before it, and its outputs reach the host before its "done" (lockstep SIL stays
deterministic).

The child is started with the "spawn" method (the host has threads; fork would copy their locks)
and builds its module from the registry by kind (`host.modules.KINDS`), so only modules that need
no host resources (buses, trace) can be isolated. A handshake (ready -> hello -> started) makes sure
both streams are connected before the first release: a subscriber that joins late misses what was
sent before. After the handshake the host sends the newest object of every input topic.

The supervisor sees a killed or crashed child as a dead worker (`alive()` false), a raising step as
an exception, and a hung one by its CPU time from /proc, exactly like a thread; `abandon` kills the
process. Scenario fault injection reaches process workers only by `module_kill`: exceptions, hangs
and slow-downs are injected into thread workers.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import time
import traceback
from dataclasses import dataclass
from typing import Any

from bywire.clock import Clock
from bywire.host.runtime.mcap_log import register_type
from bywire.host.runtime.module import ModuleContext, ModuleSpec
from bywire.host.runtime.store import ObjectStore
from bywire.host.runtime.worker import Failure, ReleaseStats, complete_on_record, task_cpu_time_s

HANDSHAKE_PERIOD_S = 0.01
PARENT_CHECK_S = 0.5  # how often an idle child checks that its host still exists


@register_type
@dataclass(frozen=True)
class WorkerSignal:
    """Control between host and child: hello / step / stop down, ready / started / done / error up."""

    t_s: float
    kind: str
    seq: int = 0
    pid: int = 0
    exec_s: float = 0.0
    error: str = ""
    published: int = 0  # publications of the step ("done")


def _topics(name: str, generation: int) -> tuple[str, str]:
    return f"/runtime/worker/{name}/{generation}/ctl", f"/runtime/worker/{name}/{generation}/status"


def _child_main(
    spec: ModuleSpec, kind: str, params: dict[str, Any], generation: int, in_ep: str, out_ep: str
) -> None:
    from bywire.host.modules import KINDS
    from bywire.host.runtime.transport import TopicPublisher, TopicSubscriber

    ctl_topic, status_topic = _topics(spec.name, generation)
    store = ObjectStore()
    sub = TopicSubscriber(in_ep, store)
    pub = TopicPublisher(out_ep)
    pub.attach(store, spec.outputs)
    ctl = store.subscribe(ctl_topic)
    parent = os.getppid()
    pid = os.getpid()
    try:
        while True:  # handshake: both streams connected once the host's hello gets through
            pub.send(status_topic, WorkerSignal(0.0, "ready", pid=pid))
            msg = ctl.wait(HANDSHAKE_PERIOD_S)
            if msg is not None and msg.kind == "hello":
                break
            if os.getppid() != parent:
                return
        ctx = ModuleContext(spec, store, params, generation)
        try:
            module = KINDS[kind].build(params, None)
            module.start(ctx)
        except Exception as exc:
            pub.send(status_topic, WorkerSignal(0.0, "error", pid=pid, error=f"start: {_describe(exc)}"))
            time.sleep(0.1)  # let the report leave before the process ends
            return
        pub.send(status_topic, WorkerSignal(0.0, "started", pid=pid))
        while True:
            msg = ctl.wait(PARENT_CHECK_S)
            if msg is None:
                if os.getppid() != parent:
                    return  # the host is gone: nobody will ever release us again
                continue
            if msg.kind == "stop":
                module.close()
                return
            if msg.kind != "step":
                continue
            ctx.now_s = msg.t_s
            wall0 = time.perf_counter()
            before = ctx.published
            try:
                module.step(ctx)
            except Exception as exc:
                pub.send(
                    status_topic,
                    WorkerSignal(msg.t_s, "error", msg.seq, pid, error=f"step: {_describe(exc)}"),
                )
                time.sleep(0.1)
                return
            pub.send(
                status_topic,
                WorkerSignal(
                    msg.t_s,
                    "done",
                    msg.seq,
                    pid,
                    time.perf_counter() - wall0,
                    published=ctx.published - before,
                ),
            )
    finally:
        sub.close()
        pub.close()


def _describe(exc: BaseException) -> str:
    frames = traceback.extract_tb(exc.__traceback__)
    at = f" at {os.path.basename(frames[-1].filename)}:{frames[-1].lineno}" if frames else ""
    return f"{type(exc).__name__}: {exc}{at}"


class ProcessWorker:
    """The host's handle on one module instance in a child process (the `Worker` protocol)."""

    def __init__(
        self,
        spec: ModuleSpec,
        kind: str,
        params: dict[str, Any],
        store: ObjectStore,
        clock: Clock,
        generation: int,
    ) -> None:
        from bywire.host.runtime.transport import TopicPublisher, TopicSubscriber, new_endpoint

        self.spec = spec
        self.generation = generation
        self.stats = ReleaseStats()
        self.failure: Failure | None = None
        self.busy_since_s: float | None = None
        self._store = store
        self._clock = clock
        self._ctl_topic, status_topic = _topics(spec.name, generation)
        store.declare(status_topic, WorkerSignal, history=64)
        self._status = store.subscribe(status_topic)
        in_ep = new_endpoint(f"{spec.name}-{generation}-in")
        out_ep = new_endpoint(f"{spec.name}-{generation}-out")
        self._pub = TopicPublisher(in_ep)
        self._pub.attach(store, spec.inputs)
        self._sub = TopicSubscriber(out_ep, store)
        self._seq = 0
        self._started = False
        self._closed = False
        ctx = mp.get_context("spawn")
        self.process = ctx.Process(
            target=_child_main,
            args=(spec, kind, {k: v for k, v in params.items() if k != "kind"}, generation, in_ep, out_ep),
            name=f"bywire-{spec.name}#{generation}",
            daemon=True,
        )
        self.process.start()
        self.pid: int | None = self.process.pid

    # -- the control stream --------------------------------------------------------------------------

    def _pump(self) -> None:
        for sig in self._status:
            self._handle_one(sig)

    def ready(self) -> bool:
        self._pump()
        return self._started or self.failure is not None

    def wait_started(self, timeout_s: float) -> bool:
        end = time.monotonic() + timeout_s
        while not self.ready():
            if not self.process.is_alive() or time.monotonic() > end:
                return False
            self._status_wait(min(HANDSHAKE_PERIOD_S, end - time.monotonic()))
        return True

    def _status_wait(self, timeout_s: float) -> None:
        sig = self._status.wait(max(0.0, timeout_s))
        if sig is not None:
            self._handle_one(sig)

    def _handle_one(self, sig: WorkerSignal) -> None:
        if sig.kind == "ready":
            # Answered every time: the child may not have been listening for the first hello.
            self._pub.send(self._ctl_topic, WorkerSignal(0.0, "hello"))
        elif sig.kind == "started" and not self._started:
            self._started = True
            for topic in self.spec.inputs:
                obj = self._store.latest(topic)
                if obj is not None:
                    self._pub.send(topic, obj)
        elif sig.kind == "done" and sig.seq == self._seq and self.busy_since_s is not None:
            complete_on_record(
                self.spec, self.stats, self.busy_since_s, self._clock.now(), sig.exec_s, sig.published > 0
            )
            self.busy_since_s = None
        elif sig.kind == "error":
            self.failure = Failure("exception", sig.error, self._clock.now())
            self.busy_since_s = None

    # -- the Worker protocol -------------------------------------------------------------------------

    def release(self, now_s: float) -> bool:
        self._pump()
        if self.failure is not None or not self._started:
            return False
        if self.busy_since_s is not None:
            self.stats.skipped += 1
            return False
        self._seq += 1
        self.busy_since_s = self._clock.now()  # the real release instant (a chain releases late)
        self.stats.releases += 1
        self.stats.last_release_s = now_s
        self._pub.send(self._ctl_topic, WorkerSignal(now_s, "step", self._seq))
        return True

    def wait_done(self, timeout_s: float) -> bool:
        end = time.monotonic() + timeout_s
        self._pump()
        while self.busy_since_s is not None and self.failure is None:
            remaining = end - time.monotonic()
            if remaining <= 0 or not self.process.is_alive():
                self._pump()
                return self.busy_since_s is None
            self._status_wait(min(remaining, 0.05))
        return True

    def alive(self) -> bool:
        self._pump()
        return self.process.is_alive()

    def cpu_time_s(self) -> float | None:
        return None if self.pid is None else task_cpu_time_s(self.pid, self.pid)

    def abandon(self) -> None:
        self.process.kill()
        self._close()

    def retire(self) -> None:
        if self.process.is_alive():
            self._pub.send(self._ctl_topic, WorkerSignal(self._clock.now(), "stop"))
            self.process.join(timeout=0.5)
            if self.process.is_alive():
                self.process.kill()
        self._close()

    def _close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._sub.close()  # nothing of this instance reaches the store any more (the fence)
        self._pub.close()
        self.process.join(timeout=1.0)


def process_worker_maker(lockstep: bool) -> Any:
    """The `Runtime`'s factory for process workers (kind and parameters come from the entry)."""

    def make(entry: Any, store: ObjectStore, clock: Clock, injector: Any) -> ProcessWorker:
        params = dict(entry.params)
        return ProcessWorker(entry.spec, str(params.get("kind")), params, store, clock, entry.generation)

    return make

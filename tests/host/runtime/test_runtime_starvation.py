"""Lockstep charges a module step only the time it used: a step kept off the CPU by another
process is neither a deadline miss nor a hang (host/runtime/inline_worker.py).

Each case runs in a subprocess of its own, which pins the scheduler's thread to one CPU, drops it
to SCHED_IDLE for the step and wakes a busy "hog" process pinned to the same CPU: the step is
runnable but gets (almost) no CPU for `hog_s`, as it would on a loaded machine or a VM whose vCPU
the hypervisor took away. The subprocess keeps the priority and affinity changes out of pytest.
Marked `hil`: like the real-time runs, the cases need the machine to themselves (with another
busy test beside them the hog's own timing is not what the case assumes).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import pytest

pytestmark = pytest.mark.hil

SCRIPT = textwrap.dedent(
    r"""
    import json, os, subprocess, sys, time
    from dataclasses import dataclass

    import bywire.host.runtime.inline_worker as inline_worker

    poll_s, hog_s, work_s, mode = float(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3]), sys.argv[4]
    inline_worker.POLL_S = poll_s  # before the first worker starts the watchdog

    from bywire.clock import SimClock
    from bywire.host.runtime.module import FailurePolicy, Module, ModuleSpec
    from bywire.host.runtime.runtime import Runtime
    from bywire.host.runtime.store import ObjectStore

    CPU = sorted(os.sched_getaffinity(0))[-1]
    HOG = (
        "import os, sys, time\n"
        f"os.sched_setaffinity(0, {{{CPU}}})\n"
        "for line in sys.stdin:\n"
        "    end = time.perf_counter() + float(line)\n"
        "    while time.perf_counter() < end:\n"
        "        pass\n"
        "    print('done', flush=True)\n"
    )
    hog = subprocess.Popen(
        [sys.executable, "-c", HOG], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )

    @dataclass(frozen=True)
    class Tick:
        t_s: float

    walls = []

    class Victim(Module):
        # Pinning and priority are set a release before and undone a release after: moving a
        # thread to another CPU makes it wait for the move, a voluntary switch of its own.
        all_cpus = os.sched_getaffinity(0)

        def step(self, ctx):
            t = round(ctx.now_s, 6)
            if mode == "starved" and t == 0.08:
                os.sched_setaffinity(0, {CPU})
                os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
            if t == 0.1:
                t0 = time.perf_counter()
                if mode == "starved":
                    hog.stdin.write(f"{hog_s}\n")
                    hog.stdin.flush()
                    cpu0 = time.thread_time()
                    while time.thread_time() - cpu0 < work_s:  # its work, whenever it gets the CPU
                        pass
                else:
                    time.sleep(hog_s)  # waits by itself: charged the wall time
                walls.append(time.perf_counter() - t0)
            if mode == "starved" and t == 0.12:
                os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
                os.sched_setaffinity(0, self.all_cpus)
                hog.stdout.readline()
            ctx.publish("/v", Tick(ctx.now_s))

    store = ObjectStore()
    rt = Runtime(store, SimClock(), lockstep=True, lockstep_timeout_s=0.04)
    policy = FailurePolicy(hang_after_s=0.06)
    rt.add_module(ModuleSpec("v", outputs=("/v",), period_s=0.02, deadline_s=0.01, policy=policy), Victim)
    rt.start(0.0)
    try:
        for k in range(301):
            rt.clock.advance_to(k * 0.001)
            rt.tick(k * 0.001)
    finally:
        rt.close()
        hog.stdin.close()
        hog.wait(5)
    module = rt.summary(0.3)["modules"]["v"]
    print(json.dumps({
        "wall_s": walls,
        "misses": module["misses"],
        "events": [[e.module, e.cause, e.action] for e in rt.events],
        "latest_s": store.latest("/v").t_s,
    }))
    """
)


def run_case(poll_s: float, hog_s: float, mode: str, work_s: float = 0.002) -> dict:
    if len(os.sched_getaffinity(0)) < 2:
        pytest.skip("needs two CPUs: the hog takes one, the watchdog thread runs on the other")
    out = subprocess.run(
        [sys.executable, "-c", SCRIPT, str(poll_s), str(hog_s), str(work_s), mode],
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_a_step_kept_off_the_cpu_is_not_a_miss() -> None:
    # The watchdog stays asleep through the step (poll 10 s), so nothing takes the GIL in between.
    r = run_case(poll_s=10.0, hog_s=0.03, mode="starved")
    assert r["wall_s"][0] > 0.025, "the hog did not take the CPU: the case shows nothing"
    assert r["misses"] == 0 and r["events"] == [], r
    assert r["latest_s"] == pytest.approx(0.3)


def test_a_step_that_waits_by_itself_is_charged_the_wall_time() -> None:
    r = run_case(poll_s=10.0, hog_s=0.03, mode="sleep")
    assert r["wall_s"][0] > 0.025
    assert r["misses"] == 1 and r["events"] == [], r


def test_a_step_starved_past_the_watchdog_timeout_is_not_judged_a_hang_or_deadlock() -> None:
    # 150 ms without CPU, well past the 40 ms lockstep timeout and through several watchdog polls,
    # then 30 ms of work (within the timeout): before, the watchdog saw the step late and, once it ran
    # again, using the CPU: a "hang", interrupted and restarted.
    r = run_case(poll_s=0.01, hog_s=0.15, mode="starved", work_s=0.03)
    assert r["events"] == [], r
    assert r["wall_s"][0] > 0.14, "the hog did not take the CPU: the case shows nothing"
    assert r["latest_s"] == pytest.approx(0.3)

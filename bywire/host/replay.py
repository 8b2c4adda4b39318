"""Replay: feed a recording back through the host's modules on simulated time, and compare.

In the spirit of openpilot's process replay: a recording carries its host configuration and what its
mission came from (`/run/info`), so it can be replayed on its own. The modules that compute
rather than talk to hardware (kinds that need no host resources: odometry, the lead tracker, the
longitudinal controller) are rebuilt, fresh, from the recorded configuration; every other topic of
the recording is an input, published into a new store at its recorded time. Each replayed module is
released exactly when it was released in the run — at the times of its recorded outputs, since a
module publishes every release — on a simulated clock, inputs of that instant first, then the
modules in dependency order, as the scheduler's chain ran them. Their outputs are compared with
the recorded ones, release by release, field by field.

Tolerances: the recording stores floats exactly (shortest round-trip repr), and replay runs the same
code on the same inputs, so the default tolerance is exact equality up to `DEFAULT_ABS_TOL`
(1e-9, in the field's SI unit) plus `DEFAULT_REL_TOL` (1e-9): room for a platform's libm, nothing
more. Replaying a log twice gives identical outputs.

What a replay cannot reproduce, it refuses or says: a module restarted by the supervisor during the
run is restarted at the same instant in the replay (fresh state, as in the run); a replayed module
that consumes a topic produced after it in the chain (a feedback input of the same instant) is
refused, since its view of that instant's data is not in the recording.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bywire.clock import SimClock
from bywire.host.config import HostConfig, parse_host_config
from bywire.host.inputs import HostInputs, lane_map_file
from bywire.host.modules import KINDS, HostResources
from bywire.host.modules.messages import RUN_INFO, RunInfo
from bywire.host.runtime.can_frame import CAN_TOPIC_PREFIX
from bywire.host.runtime.log_schema import LogError
from bywire.host.runtime.mcap_reader import read_objects
from bywire.host.runtime.module import Module, ModuleContext, ModuleSpec, dependency_order
from bywire.host.runtime.store import ObjectStore
from bywire.host.runtime.topics import SAFETY_LIMIT, STOP_REQUEST, SUPERVISOR_EVENTS, SupervisorEvent

DEFAULT_ABS_TOL = 1e-9
DEFAULT_REL_TOL = 1e-9
MAX_REPORTED = 20  # mismatches listed per topic
SUPERVISOR_TOPICS = (SAFETY_LIMIT, STOP_REQUEST)


class ReplayError(ValueError):
    """A recording that cannot be replayed, and why."""


@dataclass
class TopicComparison:
    recorded: int = 0
    replayed: int = 0
    compared: int = 0
    mismatched: int = 0
    max_abs_diff: dict[str, float] = field(default_factory=dict)
    first_mismatches: list[str] = field(default_factory=list)


@dataclass
class ReplayResult:
    file: str
    modules: list[str]
    inputs: list[str]
    releases: int
    restarts: int
    topics: dict[str, TopicComparison]
    outputs: dict[str, list[Any]]  # the replayed objects, per output topic

    @property
    def matches(self) -> bool:
        return all(c.mismatched == 0 and c.recorded == c.replayed == c.compared for c in self.topics.values())

    def to_json(self) -> dict[str, Any]:
        return {
            "file": self.file,
            "matches": self.matches,
            "modules": self.modules,
            "inputs": self.inputs,
            "releases": self.releases,
            "restarts": self.restarts,
            "tolerance": {"abs": DEFAULT_ABS_TOL, "rel": DEFAULT_REL_TOL},
            "topics": {t: dataclasses.asdict(c) for t, c in self.topics.items()},
        }


def _load(path: Path) -> tuple[RunInfo, dict[str, list[Any]]]:
    by_topic: dict[str, list[Any]] = defaultdict(list)
    info: RunInfo | None = None
    for entry in read_objects(path):
        if entry.topic.startswith((CAN_TOPIC_PREFIX, "/runtime/")):
            continue  # frames went to adapters that are not replayed; health and workers are the runtime's
        if entry.topic == RUN_INFO and isinstance(entry.obj, RunInfo):
            info = info or entry.obj
            continue
        if isinstance(entry.obj, dict):
            raise ReplayError(
                f"{path}: topic {entry.topic}: type {entry.schema_name} is unknown to this version"
            )
        by_topic[entry.topic].append(entry.obj)
    if info is None:
        raise ReplayError(f"{path}: no {RUN_INFO} in the recording: it was not made by a bywire host")
    return info, by_topic


def _rebuild(info: RunInfo, path: Path) -> HostConfig:
    try:
        return parse_host_config(json.loads(info.host_config_json), f"{path}:{RUN_INFO}:host_config")
    except ValueError as exc:
        raise ReplayError(f"{path}: the recorded host configuration does not load: {exc}") from exc


def car_run_inputs(info: RunInfo) -> HostInputs:
    """The mission of a recording made by `bywire host run` on a car: its files, where they were. A
    recording of a simulator's scenario needs the simulator's reader (`hil.host_inputs.recorded_inputs`)
    for a module that reads the mission (the world model's lane map); the others replay without it."""
    try:
        args = json.loads(info.scenario_text) if info.scenario_text.startswith("{") else None
    except ValueError:
        args = None
    if not isinstance(args, dict):

        def not_here() -> Any:
            raise ReplayError(
                f"the recording's mission ({info.scenario_source}) is a simulator scenario: "
                "replay it with `bywire log replay`, which rebuilds it"
            )

        return HostInputs(lane_map=not_here, source=info.scenario_source)
    lane_map = args.get("lane_map")
    return HostInputs(
        rndf=args.get("rndf"),
        mdf=args.get("mdf"),
        lane_map=lane_map_file(lane_map) if lane_map else None,
        source=info.scenario_source,
    )


def _check_chain(specs: list[ModuleSpec], replayed: set[str]) -> None:
    order = [s.name for s in dependency_order(specs)]
    producer = {t: s.name for s in specs for t in s.outputs}
    for s in specs:
        if s.name not in replayed:
            continue
        for topic in s.inputs:
            src = producer.get(topic)
            if src is not None and src not in replayed and order.index(src) > order.index(s.name):
                raise ReplayError(
                    f"module {s.name} reads {topic} from {src}, which runs after it in the chain: "
                    "the recording does not hold what it saw of that instant"
                )


def _equal(a: Any, b: Any, path: str, diffs: dict[str, float]) -> list[str]:
    """Differences between a recorded and a replayed value beyond the tolerance, as 'field: a != b'."""
    if isinstance(a, float) or isinstance(b, float):
        fa, fb = float(a), float(b)
        if math.isnan(fa) and math.isnan(fb):
            return []
        d = abs(fa - fb)
        if not math.isnan(d):
            diffs[path] = max(diffs.get(path, 0.0), d)
        if fa == fb or d <= DEFAULT_ABS_TOL + DEFAULT_REL_TOL * max(abs(fa), abs(fb)):
            return []
        return [f"{path}: recorded {fa!r}, replayed {fb!r}"]
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        # a perception frame's arrays (a revolution's points, the grid's obstacle cells): same shape,
        # and elementwise within the tolerance
        xa, xb = np.asarray(a), np.asarray(b)
        if xa.shape != xb.shape:
            return [f"{path}: recorded shape {xa.shape}, replayed {xb.shape}"]
        if xa.size == 0:
            return []
        if not (np.issubdtype(xa.dtype, np.number) and np.issubdtype(xb.dtype, np.number)):
            return [] if np.array_equal(xa, xb) else [f"{path}: recorded and replayed arrays differ"]
        va, vb = xa.astype(np.float64), xb.astype(np.float64)
        both_nan = np.isnan(va) & np.isnan(vb)
        gap = np.where(both_nan, 0.0, np.abs(va - vb))
        worst = float(np.nanmax(gap)) if not np.isnan(gap).all() else math.nan
        if not math.isnan(worst):
            diffs[path] = max(diffs.get(path, 0.0), worst)
        bound = DEFAULT_ABS_TOL + DEFAULT_REL_TOL * np.maximum(np.abs(va), np.abs(vb))
        bad = ~(both_nan | (gap <= bound))
        if not bad.any():
            return []
        i = int(np.flatnonzero(bad.ravel())[0])
        return [f"{path}: {int(bad.sum())} elements differ, first [{i}]: recorded {va.ravel()[i]!r}, "
                f"replayed {vb.ravel()[i]!r}"]  # fmt: skip
    if dataclasses.is_dataclass(a) and dataclasses.is_dataclass(b):
        out: list[str] = []
        for f in dataclasses.fields(a):
            out += _equal(
                getattr(a, f.name), getattr(b, f.name), f"{path}.{f.name}" if path else f.name, diffs
            )
        return out
    if isinstance(a, tuple | list) and isinstance(b, tuple | list) and len(a) == len(b):
        out = []
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            out += _equal(x, y, f"{path}[{i}]", diffs)
        return out
    return [] if a == b else [f"{path}: recorded {a!r}, replayed {b!r}"]


class _Instance:
    def __init__(self, spec: ModuleSpec, build: Any, store: ObjectStore, generation: int) -> None:
        self.ctx = ModuleContext(spec, store, {}, generation)
        self.module: Module = build()
        self.module.start(self.ctx)


def replay(
    path: Path,
    modules: list[str] | None = None,
    inputs_for: Callable[[RunInfo], HostInputs] = car_run_inputs,
) -> ReplayResult:
    """Replay `path` through its computing modules (or the named ones) and compare their outputs.
    `inputs_for` rebuilds the recorded mission (`car_run_inputs`, or the simulator's reader)."""
    path = Path(path)
    info, recorded = _load(path)
    config = _rebuild(info, path)
    specs = [m.spec for m in config.modules]
    pure = [m for m in config.modules if not KINDS[m.kind].needs_resources]
    if modules is not None:
        unknown = sorted(set(modules) - {m.spec.name for m in pure})
        if unknown:
            replayable = ", ".join(m.spec.name for m in pure)
            raise ReplayError(f"cannot replay {', '.join(unknown)}: replayable modules are {replayable}")
        pure = [m for m in pure if m.spec.name in modules]
    names = {m.spec.name for m in pure}
    _check_chain(specs, names)
    order = [s for s in dependency_order(specs) if s.name in names]
    cfg = {m.spec.name: m for m in pure}
    outputs = {t for s in order for t in s.outputs}
    inputs = sorted(t for t in recorded if t not in outputs and t != SUPERVISOR_EVENTS)

    # The schedule: inputs at their times; each module at the times of its recorded releases
    # (its first output topic's objects); supervisor restarts of replayed modules at theirs. The
    # supervisor acts after a tick's releases, so its topics and restarts come last at an instant.
    events: list[tuple[float, int, int, Any]] = []  # (t, phase, rank, payload)
    for topic in inputs:
        phase = 3 if topic in SUPERVISOR_TOPICS else 0
        for obj in recorded[topic]:
            events.append((obj.t_s, phase, 0, (topic, obj)))
    restarts = [
        e
        for e in recorded.get(SUPERVISOR_EVENTS, [])
        if isinstance(e, SupervisorEvent) and e.module in names and e.action == "restart"
    ]
    for ev in restarts:
        events.append((ev.t_s, 4, 0, ev.module))
    for rank, spec in enumerate(order):
        for obj in recorded.get(spec.outputs[0], []):
            events.append((obj.t_s, 2, rank, spec.name))
    events.sort(key=lambda e: (e[0], e[1], e[2]))

    store = ObjectStore(default_history=4096)
    clock = SimClock(events[0][0] if events else 0.0)
    resources = HostResources(inputs_for(info), info.t_s)
    builders = {
        s.name: (
            lambda kind=cfg[s.name].kind, params=cfg[s.name].params: KINDS[kind].build(params, resources)
        )
        for s in order
    }
    live: dict[str, _Instance] = {}
    generation: dict[str, int] = defaultdict(int)
    replayed: dict[str, list[Any]] = {t: [] for t in outputs}
    store.add_tap(lambda topic, obj: replayed[topic].append(obj) if topic in replayed else None)
    releases = 0
    last_release: dict[str, float] = {}
    for t, phase, _, payload in events:
        clock.advance_to(max(clock.now(), t))
        if phase in (0, 3):
            topic, obj = payload
            store.publish(topic, obj)
            continue
        name = payload
        if phase == 4:
            live.pop(name, None)  # the next release builds a fresh instance, as the restart did
            continue
        if last_release.get(name) == t:
            continue  # one release per instant (a module publishing two outputs is listed once)
        last_release[name] = t
        inst = live.get(name)
        if inst is None:
            generation[name] += 1
            inst = live[name] = _Instance(
                next(s for s in order if s.name == name), builders[name], store, generation[name]
            )
        inst.ctx.release(t)
        inst.module.step(inst.ctx)
        releases += 1

    topics: dict[str, TopicComparison] = {}
    for topic in sorted(outputs):
        rec, rep = recorded.get(topic, []), replayed[topic]
        c = TopicComparison(recorded=len(rec), replayed=len(rep))
        for i, (a, b) in enumerate(zip(rec, rep, strict=False)):
            c.compared += 1
            problems = _equal(a, b, "", c.max_abs_diff)
            if problems:
                c.mismatched += 1
                if len(c.first_mismatches) < MAX_REPORTED:
                    c.first_mismatches.append(f"#{i} t={a.t_s:.6f}: " + "; ".join(problems[:3]))
        topics[topic] = c
    return ReplayResult(
        file=str(path),
        modules=[s.name for s in order],
        inputs=inputs,
        releases=releases,
        restarts=len(restarts),
        topics=topics,
        outputs=replayed,
    )


__all__ = ["LogError", "ReplayError", "ReplayResult", "replay"]

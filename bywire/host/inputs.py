"""What a host agent is given to drive, besides its configuration and its buses: the mission.

On a car it comes from the command line (`bywire host run`): an RNDF and an MDF for urban driving
(seed 000 section 7), a lane map recorded with `bywire platoon record-map` for platooning (seed 003
section IV-A; its origin anchors the local frame), and a command script for the spine's cruise
(`host.command_script`). In the simulator, `hil.host_inputs` builds the same object from a scenario.

`HostFaultHooks` is the one door through which a test harness may act on a running host: module
faults, the host stopping (in SIL, the stand-in for freezing or killing its process) and a muted
heartbeat. A car's host runs with `NO_FAULTS`; the simulator hands in its own.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from bywire.host.command_script import CommandScript

GCDC_EPOCH_UNIX_S = 1305374400.0  # 2011-05-14, the GCDC final: V2V time of a simulated clock's zero


@dataclass(frozen=True)
class HostInputs:
    commands: CommandScript = field(default_factory=CommandScript)
    rndf: str | None = None  # urban driving: the road network ...
    mdf: str | None = None  # ... and the mission on it
    # Built on first use (a pyproj frame ~0.1 s, a lane map ~1 s). The lane map's origin is the frame's.
    lane_map: Callable[[], Any] | None = None  # -> host.world.lanemap.LaneMap
    local_frame: Callable[[], Any] | None = None  # -> host.geo.LocalFrame
    station_id: int = 1  # our V2V station id (a module's `station_id` parameter overrides it)
    v2v_epoch_unix_s: float = GCDC_EPOCH_UNIX_S  # UNIX time of runtime zero when no wall clock is given
    duration_s: float | None = None  # None: until stopped
    source: str = "<command line>"  # what the mission came from, and its text: recorded for replay
    source_text: str = ""

    def frame(self) -> Any:
        if self.local_frame is not None:
            return self.local_frame()
        if self.lane_map is not None:
            return self.lane_map().frame
        raise ValueError(
            f"{self.source}: the pose and V2V modules need a local frame: give a lane map (--lane-map)"
        )


def lane_map_file(path: str | Path) -> Callable[[], Any]:
    """A lane map file, loaded once on first use (`LaneMapError` with file and field when it is bad)."""
    cache: list[Any] = []

    def load() -> Any:
        if not cache:
            from bywire.host.world.lanemap import LaneMap

            cache.append(LaneMap.load(Path(path)))
        return cache[0]

    return load


class HostFaultHooks(Protocol):
    """Fault injection into a running host (see the module docstring); times on the runtime clock."""

    t0_s: float  # the run's start: set by the host when it learns it

    def before_step(self, module: str, ctx: Any) -> None: ...

    def tick(self, runtime: Any, now_s: float) -> None: ...

    def host_stopped(self, now_s: float) -> bool: ...

    def heartbeat_muted(self, now_s: float) -> bool: ...


class NoFaults:
    """A car's host: nothing is injected."""

    t0_s = 0.0

    def before_step(self, module: str, ctx: Any) -> None:
        pass

    def tick(self, runtime: Any, now_s: float) -> None:
        pass

    def host_stopped(self, now_s: float) -> bool:
        return False

    def heartbeat_muted(self, now_s: float) -> bool:
        return False

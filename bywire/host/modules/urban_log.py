"""What the urban host's modules log for the run's summary: the behaviour's state history, its faults, the
checkpoints it counted, the object datagrams the link rejected, and for judging the perception against
the simulator's truth: the object lists the behaviour read (every `SAMPLE_S` of their stamps) and the
map offset the controller applied (every `SAMPLE_S` of its clock).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

SAMPLE_S = 0.5  # the world's truth is sampled as often (hil.world.urban.TRACK_SAMPLE_S)


@dataclass
class UrbanLog:
    """What the urban modules tell the run's summary: the state history and the faults (not data flow)."""

    states: list[tuple[float, str]] = field(default_factory=list)
    faults: list[tuple[float, str]] = field(default_factory=list)
    checkpoints_reached: tuple[int, ...] = ()
    reverse_held: int = 0
    rejected: int = 0
    # (scenario stamp of the list, ((object id, x_m, y_m), ...))
    perceived: list[tuple[float, tuple[tuple[str, float, float], ...]]] = field(default_factory=list)
    # (runtime clock, offset applied m (0: none), offset valid)
    lane_offsets: list[tuple[float, float, bool]] = field(default_factory=list)

    def perceive(self, stamp_s: float, objects: tuple[tuple[str, float, float], ...]) -> None:
        if not self.perceived or stamp_s >= self.perceived[-1][0] + SAMPLE_S - 1e-9:
            self.perceived.append((stamp_s, objects))

    def lane_offset(self, t_s: float, offset_m: float, valid: bool) -> None:
        if not self.lane_offsets or t_s >= self.lane_offsets[-1][0] + SAMPLE_S - 1e-9:
            self.lane_offsets.append((t_s, offset_m, valid))

    def summary(self) -> dict[str, Any]:
        return {
            "states": [[round(t, 3), s] for t, s in self.states],
            "faults": [[round(t, 3), f] for t, f in self.faults],
            "behaviour_checkpoints": list(self.checkpoints_reached),
            "reverse_held": self.reverse_held,
            "object_datagrams_rejected": self.rejected,
            "perceived": [
                [round(t, 3), [[i, round(x, 2), round(y, 2)] for i, x, y in objs]]
                for t, objs in self.perceived
            ],
            "lane_offsets": [[round(t, 3), round(d, 3), v] for t, d, v in self.lane_offsets],
        }

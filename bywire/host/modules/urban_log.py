"""What the urban host's modules log for the run's summary: the behaviour's state history, its faults, the
checkpoints it counted, and the object datagrams the link rejected.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


@dataclass
class UrbanLog:
    """What the urban modules tell the run's summary: the state history and the faults (not data flow)."""

    states: list[tuple[float, str]] = field(default_factory=list)
    faults: list[tuple[float, str]] = field(default_factory=list)
    checkpoints_reached: tuple[int, ...] = ()
    reverse_held: int = 0
    rejected: int = 0

    def summary(self) -> dict[str, Any]:
        return {
            "states": [[round(t, 3), s] for t, s in self.states],
            "faults": [[round(t, 3), f] for t, f in self.faults],
            "behaviour_checkpoints": list(self.checkpoints_reached),
            "reverse_held": self.reverse_held,
            "object_datagrams_rejected": self.rejected,
        }

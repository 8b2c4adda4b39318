"""The rhythm of a periodic process: the distribution of the gaps between its events.

DESIGN section 4's timing budget is a statement about gaps (a scheduler tick, a heartbeat, a received
request, a 1 kHz step); a stall recorder names the gaps that broke it, this counts all of them, so a
run's report can give p50 / p99 / p99.9 / max of each rhythm and runs can be merged. Pure Python with
constant memory, so the ECU firmware image carries it too (the node counts the host's heartbeats).
"""

from __future__ import annotations

import math
from typing import Any


class GapHistogram:
    """The distribution of the gaps between events (beats, received frames) in bins of `bin_ms`, up to
    `span_ms` (longer ones count in the last bin; the maximum is kept exactly). Constant memory and
    O(1) per event, so a process can keep one for a whole drive."""

    def __init__(self, bin_ms: float = 0.1, span_ms: float = 1000.0) -> None:
        self.bin_s = bin_ms / 1e3
        self.bins = [0] * (round(span_ms / bin_ms) + 1)
        self.count = 0
        self.max_s = 0.0
        self.max_at_s: float | None = None  # when the longest gap ended

    def add(self, gap_s: float, at_s: float | None = None) -> None:
        i = int(gap_s / self.bin_s) if gap_s > 0.0 else 0
        self.bins[min(i, len(self.bins) - 1)] += 1
        self.count += 1
        if gap_s > self.max_s:
            self.max_s = gap_s
            self.max_at_s = at_s

    def merge(self, other: GapHistogram) -> None:
        if len(other.bins) != len(self.bins) or other.bin_s != self.bin_s:
            raise ValueError("gap histograms of different bins cannot be merged")
        self.bins = [a + b for a, b in zip(self.bins, other.bins, strict=True)]
        self.count += other.count
        if other.max_s > self.max_s:
            self.max_s, self.max_at_s = other.max_s, other.max_at_s

    def quantile_ms(self, q: float) -> float:
        """The upper edge of the bin holding the q-quantile (the maximum if that is smaller)."""
        if self.count == 0:
            return 0.0
        rank = max(1, math.ceil(q * self.count - 1e-9))  # nearest rank, as the benchmarks count
        seen = 0
        for i, n in enumerate(self.bins):
            seen += n
            if seen >= rank:
                return round(min((i + 1) * self.bin_s, self.max_s) * 1e3, 3)
        return round(self.max_s * 1e3, 3)

    def summary(self) -> dict[str, Any]:
        return {
            "count": self.count,
            "p50": self.quantile_ms(0.5),
            "p99": self.quantile_ms(0.99),
            "p999": self.quantile_ms(0.999),
            "max": round(self.max_s * 1e3, 3),
        }

    def to_json(self) -> dict[str, Any]:
        """Summary plus the non-empty bins, so that runs can be merged later (`from_json`)."""
        return {
            **self.summary(),
            "bin_ms": self.bin_s * 1e3,
            "bins": {str(i): n for i, n in enumerate(self.bins) if n},
            "max_at_s": self.max_at_s,
        }

    @classmethod
    def from_json(cls, doc: dict[str, Any], span_ms: float = 1000.0) -> GapHistogram:
        h = cls(float(doc["bin_ms"]), span_ms)
        for i, n in doc["bins"].items():
            h.bins[min(int(i), len(h.bins) - 1)] += int(n)
        h.count = int(doc["count"])
        h.max_s = float(doc["max"]) / 1e3
        h.max_at_s = doc.get("max_at_s")
        return h

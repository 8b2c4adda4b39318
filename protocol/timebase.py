"""Putting received frames on the receiver's clock.

python-can stamps frames with `time.time()` (socketcan, the remote server's virtual bus), our loops
run on CLOCK_MONOTONIC or on simulated time. Staleness checks compare a frame's receive time with
`now_s`, so both must be on one time base: this converts an epoch stamp to the monotonic clock and
leaves stamps that are already on the receiver's clock (SIL's simulated time) alone.
"""

from __future__ import annotations

import time

import can

EPOCH_GUESS_S = 1.0e8  # no monotonic clock or simulation on these machines runs for 3 years


def rx_time_s(msg: can.Message, now_s: float) -> float:
    """The frame's receive time on the clock of `now_s`; `now_s` itself when the frame has no stamp."""
    ts = msg.timestamp
    if not ts:
        return now_s
    if ts > EPOCH_GUESS_S and now_s < EPOCH_GUESS_S:
        return ts - (time.time() - time.monotonic())
    return ts

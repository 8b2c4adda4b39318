"""Frames and clocks: received frames on the receiver's clock, frames to send stamped cheaply.

python-can stamps frames with `time.time()` (socketcan, the remote server's virtual bus), our loops
run on CLOCK_MONOTONIC or on simulated time. Staleness checks compare a frame's receive time with
`now_s`, so both must be on one time base: `rx_time_s` converts an epoch stamp to the monotonic
clock and leaves stamps that are already on the receiver's clock (SIL's simulated time) alone.

`data_frame` builds the frames the codecs send (a few hundred a second in SIL, for the ECU and the
plant) slot by slot: `can.Message(...)`'s keyword handling cost several times the encoding itself.
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


# The slots can.Message has in the python-can versions `data_frame` was written against; with any
# other layout frames go through the constructor (tests/hil/test_sil_bus.py compares the two).
MESSAGE_SLOTS = frozenset(
    {
        "__weakref__",
        "arbitration_id",
        "bitrate_switch",
        "channel",
        "data",
        "dlc",
        "error_state_indicator",
        "is_error_frame",
        "is_extended_id",
        "is_fd",
        "is_remote_frame",
        "is_rx",
        "timestamp",
    }
)
SLOT_LAYOUT_KNOWN = (
    frozenset(can.Message.__slots__) == MESSAGE_SLOTS and can.Message.__new__ is object.__new__
)
_new = object.__new__


def data_frame(arbitration_id: int, data: bytearray, timestamp_s: float = 0.0) -> can.Message:
    """`can.Message(timestamp=timestamp_s, arbitration_id=arbitration_id, is_extended_id=False,
    data=data)`: a classical 11-bit data frame owning `data` (a bytearray, not copied)."""
    if not SLOT_LAYOUT_KNOWN:
        return can.Message(
            timestamp=timestamp_s, arbitration_id=arbitration_id, is_extended_id=False, data=data
        )
    msg: can.Message = _new(can.Message)
    msg.timestamp = timestamp_s
    msg.arbitration_id = arbitration_id
    msg.is_extended_id = False
    msg.is_remote_frame = False
    msg.is_error_frame = False
    msg.channel = None
    msg.is_fd = False
    msg.is_rx = True  # python-can's default
    msg.bitrate_switch = False
    msg.error_state_indicator = False
    msg.data = data
    msg.dlc = len(data)
    return msg

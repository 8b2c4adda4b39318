"""CAN frames as recorded messages: `CanFrame` on the topics `/can/<bus>`.

Seed 000 section 3: every bus frame of a run is logged beside the runtime's objects (DESIGN.md
section 1, record/replay). A frame is an ordinary registered message type (`log_schema`), so the
recorder, the reader and the live view treat it like any other; its schema name is fixed
(`bywire.CanFrame`) so that recordings outlive moves of this class.
"""

from __future__ import annotations

from dataclasses import dataclass

import can

from bywire.host.runtime.log_schema import register_type

CAN_TOPIC_PREFIX = "/can/"
CAN_FRAME_SCHEMA = "bywire.CanFrame"


@dataclass(frozen=True, slots=True)
class CanFrame:
    """A CAN frame as recorded on `/can/<bus>`: python-can's fields; `data` as integers so Foxglove
    can plot single bytes (`/can/vehicle.data[2]`)."""

    timestamp: float
    arbitration_id: int
    is_extended_id: bool
    is_remote_frame: bool
    is_error_frame: bool
    is_fd: bool
    bitrate_switch: bool
    error_state_indicator: bool
    is_rx: bool
    dlc: int
    data: tuple[int, ...]

    @classmethod
    def from_message(cls, msg: can.Message, t_s: float | None = None) -> CanFrame:
        return cls(
            timestamp=float(msg.timestamp if t_s is None else t_s),
            arbitration_id=int(msg.arbitration_id),
            is_extended_id=bool(msg.is_extended_id),
            is_remote_frame=bool(msg.is_remote_frame),
            is_error_frame=bool(msg.is_error_frame),
            is_fd=bool(msg.is_fd),
            bitrate_switch=bool(msg.bitrate_switch),
            error_state_indicator=bool(msg.error_state_indicator),
            is_rx=bool(msg.is_rx),
            dlc=int(msg.dlc),
            data=tuple(msg.data),
        )

    def to_message(self, channel: str | None = None) -> can.Message:
        if not 0 <= self.arbitration_id < 2**29:
            raise ValueError(f"arbitration id {self.arbitration_id} is outside 0..2^29-1")
        if not 0 <= self.dlc <= 64 or len(self.data) > 64 or not all(0 <= b <= 255 for b in self.data):
            raise ValueError(f"dlc {self.dlc} / data {self.data!r} is not a CAN payload")
        return can.Message(
            timestamp=self.timestamp,
            arbitration_id=self.arbitration_id,
            is_extended_id=self.is_extended_id,
            is_remote_frame=self.is_remote_frame,
            is_error_frame=self.is_error_frame,
            channel=channel,
            dlc=self.dlc,
            data=bytes(self.data),
            is_fd=self.is_fd,
            is_rx=self.is_rx,
            bitrate_switch=self.bitrate_switch,
            error_state_indicator=self.error_state_indicator,
        )


register_type(CanFrame, name=CAN_FRAME_SCHEMA)

"""What goes on the air: every message we send or take, encoded and decoded by its ItsPduHeader.

| messageID | message | protocolVersion sent (read) | SI dataclass | module |
|---|---|---|---|---|
| 2 | CAM, EN 302 637-2 | 2 (1, 2) | `VehicleState` | `etsi_cam` |
| 4 | SPATEM, TS 103 301 | 2 (1, 2) | `SignalPhases` | `dsrc` |
| 5 | MAPEM, TS 103 301 | 2 (1, 2) | `RoadMap` | `dsrc` |
| 10 | iCLCM, GCDC 2016 | 1 (1) | `CooperativeState` | `iclcm` |

`decode` dispatches on bytes 0..1 without ASN.1 (`codec.peek_header`); each decoder holds a datagram to the
canonical encoding of what it decodes to. reference_time_s (UNIX s, the receive time) resolves the CAM's
and iCLCM's 65.536 s GenerationDeltaTime and the SPATEM/MAPEM's year; None reads the wall clock.
"""

from __future__ import annotations

from .codec import (
    MESSAGE_NAMES,
    MSG_CAM,
    MSG_ICLCM,
    MSG_MAPEM,
    MSG_SPATEM,
    READ_VERSIONS,
    DecodeReason,
    V2xDecodeError,
    VehicleState,
    peek_header,
)
from .dsrc import RoadMap, SignalPhases, decode_mapem, decode_spatem, encode_mapem, encode_spatem
from .etsi_cam import encode_cam, from_etsi_cam
from .iclcm import CooperativeState, decode_iclcm, encode_iclcm

V2xMessage = VehicleState | CooperativeState | SignalPhases | RoadMap


def encode(msg: V2xMessage, *, low_frequency: bool = True) -> bytes:
    """A message -> its UPER datagram (low_frequency: a CAM's LF container, see etsi_cam.LowFrequencyClock).
    V2xEncodeError names the field that is out of range."""
    if isinstance(msg, VehicleState):
        return encode_cam(msg, low_frequency=low_frequency)
    if isinstance(msg, CooperativeState):
        return encode_iclcm(msg)
    if isinstance(msg, SignalPhases):
        return encode_spatem(msg)
    if isinstance(msg, RoadMap):
        return encode_mapem(msg)
    raise TypeError(
        f"encode: {type(msg).__name__} is not a VehicleState, CooperativeState, SignalPhases or RoadMap"
    )


def decode(data: bytes, reference_time_s: float | None = None) -> V2xMessage:
    """A datagram -> VehicleState / CooperativeState / SignalPhases / RoadMap, or V2xDecodeError."""
    data = bytes(data)
    header = peek_header(data)
    versions = READ_VERSIONS.get(header.message_id)
    if versions is None:
        raise V2xDecodeError(
            DecodeReason.UNKNOWN_MESSAGE,
            f"messageID {header.message_id} at byte 1: we take "
            + ", ".join(f"{name} ({mid})" for mid, name in MESSAGE_NAMES.items()),
        )
    if header.protocol_version not in versions:
        raise V2xDecodeError(
            DecodeReason.BAD_VERSION,
            f"{MESSAGE_NAMES[header.message_id]} protocolVersion {header.protocol_version} at byte 0: "
            f"we read {sorted(versions)}",
        )
    if header.message_id == MSG_CAM:
        return from_etsi_cam(data, reference_time_s)
    if header.message_id == MSG_SPATEM:
        return decode_spatem(data, reference_time_s)
    if header.message_id == MSG_MAPEM:
        return decode_mapem(data, reference_time_s)
    assert header.message_id == MSG_ICLCM
    return decode_iclcm(data, reference_time_s)

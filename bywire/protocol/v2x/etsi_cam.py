"""Real ETSI CAMs (EN 302 637-2, protocolVersion 1 and 2) into our `VehicleState` (seed 003, Sec. III, IV-B).

Seed 003 Sec. IV-B: every GCDC vehicle broadcast its state vector; DESIGN section 3: V2V messages are
ETSI ITS-G5 CAM-style. Our own wire format is `codec`'s; this module reads the CAMs of other stacks
into the same dataclass, so the receiver takes both: the ETSI schema sets (read in place from
shared/data/v2x_asn1, never shipped), `from_etsi_cam` (GenerationDeltaTime's 65.536 s wrap resolved
against the receive time, the ETSI reference point moved to the vehicle centre) and `decode_any`,
which dispatches a datagram to ours or to a CAM. Units, conventions and the deviations from a CAM
are listed in `codec`'s docstring; the unit conversions are `codec`'s, used here as they are there.
"""

from __future__ import annotations

import functools
import math
import os
import time
from enum import StrEnum
from pathlib import Path
from typing import Any, Final

import asn1tools

from .codec import (
    ACCEL_UNAVAILABLE,
    GENERATION_DELTA_MODULO,
    HEADING_UNAVAILABLE,
    LENGTH_UNAVAILABLE,
    MSG_ETSI_CAM,
    OUR_MESSAGE_IDS,
    SPEED_UNAVAILABLE,
    WIDTH_UNAVAILABLE,
    DecodeReason,
    DriveDirection,
    V2xDecodeError,
    V2xMessage,
    VehicleState,
    asn1_decode,
    decode,
    heading_from_etsi,
    lat_from_etsi,
    lon_from_etsi,
    peek_header,
    scaled_from_etsi,
    timestamp_its_to_unix,
    unix_to_timestamp_its,
    yaw_rate_from_etsi,
)


class EtsiCamSchema(StrEnum):
    """The ETSI CAM schema sets in shared/data/v2x_asn1 (read in place, never shipped)."""

    CAM_1_3_2 = "cam-1.3.2"  # EN 302 637-2 v1.3.2 + ITS-Container 1.2.1: protocolVersion 1
    CAM_1_4_1 = "cam-1.4.1"  # EN 302 637-2 v1.4.1 + CDD TS 102 894-2 v1.3.1: protocolVersion 2
    CAM_2_3_1 = "cam-2.3.1"  # release 2, TS 103 900 v2.3.1 + CDD v2.4.1: protocolVersion 2


ETSI_SCHEMA_FILES: Final = {
    EtsiCamSchema.CAM_1_3_2: (
        "asn1tools__etsi__cam_pdu_descriptions_1_3_2.asn",
        "asn1tools__etsi__its_container_1_2_1.asn",
    ),
    EtsiCamSchema.CAM_1_4_1: ("vanetza__EN302637-2v141-CAM.asn", "vanetza__TS102894-2v131-CDD.asn"),
    EtsiCamSchema.CAM_2_3_1: (
        "vanetza__release2__TS103900v231-CAM.asn",
        "vanetza__release2__TS102894-2v241-CDD.asn",
    ),
}
# A real CAM decodes only with the schema of its own protocolVersion (shared SOURCES.md): release 2 reads
# every protocolVersion-2 CAM that v1.4.1 reads (it only adds extensions), so it is the choice for 2.
SCHEMA_BY_PROTOCOL_VERSION: Final = {1: EtsiCamSchema.CAM_1_3_2, 2: EtsiCamSchema.CAM_2_3_1}
ETSI_ASN1_ENV: Final = "BYWIRE_ETSI_ASN1_DIR"


class EtsiSchemaMissing(FileNotFoundError):
    """The ETSI ASN.1 files are not where we looked; the message says where and how to point at them."""


def etsi_asn1_dir() -> Path:
    """Where the ETSI schemas are: $BYWIRE_ETSI_ASN1_DIR if set, else $BYWIRE_SHARED_DATA/v2x_asn1 if set,
    else shared/data/v2x_asn1 beside the checkout. Raises EtsiSchemaMissing naming every place tried."""
    env = os.environ.get(ETSI_ASN1_ENV)
    shared = os.environ.get("BYWIRE_SHARED_DATA")
    if env:
        tried = [Path(env)]
    elif shared:
        tried = [Path(shared) / "v2x_asn1"]
    else:
        tried = [
            Path(__file__).resolve().parents[3] / "shared" / "data" / "v2x_asn1",
            Path("/work/shared/data/v2x_asn1"),
        ]
    for d in tried:
        if (d / ETSI_SCHEMA_FILES[EtsiCamSchema.CAM_1_3_2][0]).is_file():
            return d
    raise EtsiSchemaMissing(
        "ETSI CAM ASN.1 files not found in " + ", ".join(str(d) for d in tried) + f"; set {ETSI_ASN1_ENV}"
    )


@functools.cache
def _compiled_etsi(schema: EtsiCamSchema, directory: Path) -> Any:
    files = [directory / name for name in ETSI_SCHEMA_FILES[schema]]
    for f in files:
        if not f.is_file():
            raise EtsiSchemaMissing(f"{schema.value}: {f} not found")
    return asn1tools.compile_files([str(f) for f in files], "uper")


def compiled_etsi_spec(schema: EtsiCamSchema, directory: Path | None = None) -> Any:
    """The schema set compiled for UPER, cached per process (release 2 takes ~2 s, the others ~0.4 s)."""
    return _compiled_etsi(EtsiCamSchema(schema), (directory or etsi_asn1_dir()).resolve())


def decode_etsi_cam(
    frame: bytes, schema: EtsiCamSchema | None = None, directory: Path | None = None
) -> tuple[EtsiCamSchema, dict[str, Any]]:
    """A UPER CAM -> (schema used, asn1tools value). The schema defaults to the frame's protocolVersion's."""
    frame = bytes(frame)
    header = peek_header(frame)
    if schema is None:
        chosen = SCHEMA_BY_PROTOCOL_VERSION.get(header.protocol_version)
        if chosen is None:
            raise V2xDecodeError(
                DecodeReason.BAD_VERSION,
                f"CAM protocolVersion {header.protocol_version} at byte 0: we read "
                f"{sorted(SCHEMA_BY_PROTOCOL_VERSION)}",
            )
        schema = chosen
    value = asn1_decode(compiled_etsi_spec(schema, directory), "CAM", frame, f"CAM ({schema.value})")
    return schema, value


def _field(d: dict[str, Any], *names: str) -> Any:
    """The first of `names` present in d: release 2 renamed fields (messageID -> messageId, ...)."""
    for n in names:
        if n in d:
            return d[n]
    raise KeyError("/".join(names))


# Earth radius for the small reference-point shift (<= 51 m): the local radius error is < 0.5 %.
_EARTH_RADIUS_M = 6_371_008.8


def _shift_to_centre(lat: float, lon: float, etsi_heading: int, length_m: float) -> tuple[float, float]:
    """Move the ETSI reference point (front centre) back by length/2 along the heading (clockwise from N)."""
    back_m = 0.5 * length_m
    bearing = math.radians(etsi_heading / 10.0)
    north = -back_m * math.cos(bearing)
    east = -back_m * math.sin(bearing)
    dlat = math.degrees(north / _EARTH_RADIUS_M)
    dlon = math.degrees(east / (_EARTH_RADIUS_M * max(math.cos(math.radians(lat)), 1e-6)))
    return lat + dlat, lon + dlon


def resolve_generation_delta(delta_ms: int, reference_time_s: float) -> float:
    """CAM GenerationDeltaTime (TimestampIts mod 65536) -> the UNIX time nearest reference_time_s."""
    ref = unix_to_timestamp_its(reference_time_s)
    back = (ref - delta_ms) % GENERATION_DELTA_MODULO  # how far the latest matching ms lies behind ref
    ts = ref - back if back <= GENERATION_DELTA_MODULO // 2 else ref - back + GENERATION_DELTA_MODULO
    return timestamp_its_to_unix(ts)


def from_etsi_cam(
    frame_bytes: bytes,
    reference_time_s: float | None = None,
    *,
    schema: EtsiCamSchema | None = None,
    directory: Path | None = None,
    check_message_id: bool = True,
) -> VehicleState:
    """A real ETSI CAM (UPER) -> VehicleState, the schema chosen by its protocolVersion (byte 0).

    reference_time_s resolves the 65.536 s wrap of GenerationDeltaTime (the receive time; None: now, read
    from the wall clock here at the edge). The position is moved from the ETSI reference point to the
    vehicle centre when heading and length are known (see the module docstring). A CAM from a road-side
    unit (no basic vehicle high-frequency container) raises V2xDecodeError(NOT_A_VEHICLE);
    check_message_id=False accepts a header messageID other than cam(2) (asn1tools' test vectors).
    """
    used, cam = decode_etsi_cam(frame_bytes, schema, directory)
    what = f"CAM ({used.value})"
    try:
        header = cam["header"]
        message_id = _field(header, "messageID", "messageId")
        if check_message_id and message_id != MSG_ETSI_CAM:
            raise V2xDecodeError(
                DecodeReason.UNKNOWN_MESSAGE,
                f"{what}: header messageID {message_id}, a CAM has {MSG_ETSI_CAM}",
            )
        station_id = _field(header, "stationID", "stationId")
        params = cam["cam"]["camParameters"]
        choice, hf = params["highFrequencyContainer"]
        if choice != "basicVehicleContainerHighFrequency":
            raise V2xDecodeError(DecodeReason.NOT_A_VEHICLE, f"{what}: high-frequency container is {choice}")
        ref = params["basicContainer"]["referencePosition"]
        lat, lon = lat_from_etsi(ref["latitude"]), lon_from_etsi(ref["longitude"])
        heading = hf["heading"]["headingValue"]
        length = hf["vehicleLength"]["vehicleLengthValue"]
        length_m = scaled_from_etsi(length, LENGTH_UNAVAILABLE, 10.0)
        if lat is not None and lon is not None and heading != HEADING_UNAVAILABLE and length_m is not None:
            lat, lon = _shift_to_centre(lat, lon, heading, length_m)
        accel = _field(hf["longitudinalAcceleration"], "longitudinalAccelerationValue", "value")
        direction = hf["driveDirection"]
        t_ref = time.time() if reference_time_s is None else reference_time_s
        return VehicleState(
            station_id=station_id,
            generation_time_s=resolve_generation_delta(cam["cam"]["generationDeltaTime"], t_ref),
            lat_deg=lat,
            lon_deg=lon,
            heading_rad=None if heading == HEADING_UNAVAILABLE else heading_from_etsi(heading),
            speed_mps=scaled_from_etsi(hf["speed"]["speedValue"], SPEED_UNAVAILABLE, 100.0),
            yaw_rate_radps=yaw_rate_from_etsi(hf["yawRate"]["yawRateValue"]),
            accel_mps2=scaled_from_etsi(accel, ACCEL_UNAVAILABLE, 10.0),
            length_m=length_m,
            width_m=scaled_from_etsi(hf["vehicleWidth"], WIDTH_UNAVAILABLE, 10.0),
            drive_direction=None if direction == "unavailable" else DriveDirection(direction),
            lane_position=hf.get("lanePosition"),
        )
    except V2xDecodeError:
        raise
    except (KeyError, TypeError, ValueError) as e:
        raise V2xDecodeError(DecodeReason.DECODER_FAULT, f"{what}: {type(e).__name__}: {e}") from None


def decode_any(
    data: bytes, reference_time_s: float, *, etsi_cam: bool = False, directory: Path | None = None
) -> V2xMessage:
    """Ours, or (etsi_cam=True) a real CAM: dispatched on the header's messageId."""
    header = peek_header(data)
    if header.message_id in OUR_MESSAGE_IDS:
        return decode(data)
    if etsi_cam and header.message_id == MSG_ETSI_CAM:
        return from_etsi_cam(data, reference_time_s, directory=directory)
    raise V2xDecodeError(
        DecodeReason.UNKNOWN_MESSAGE,
        f"messageId {header.message_id} at byte 1: we take {sorted(OUR_MESSAGE_IDS)}"
        + (f" and ETSI CAM ({MSG_ETSI_CAM})" if etsi_cam else ""),
    )

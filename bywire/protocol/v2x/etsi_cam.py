"""ETSI CAMs (EN 302 637-2) to and from our `VehicleState` (seed 003, Sec. III, IV-B; DESIGN section 3).

What we send is a CAM of EN 302 637-2 v1.4.1 (protocolVersion 2, CDD TS 102 894-2 v1.3.1), as every
Release-1 ITS-G5 stack sends and reads it. Seed 003's state vector maps onto it so:

- basic container: stationType (passengerCar unless said otherwise), referencePosition = the ETSI
  reference point, the ground centre of the front of the bounding box: our vehicle centre moved forward
  by half the length along the heading (back again on receipt, `_shift_along`); position confidence and
  altitude "unavailable".
- high-frequency container (every CAM): heading, speed, driveDirection, vehicleLength (noTrailerPresent),
  vehicleWidth, longitudinalAcceleration, curvature, curvatureCalculationMode, yawRate, and lanePosition
  when known. Curvature is yaw rate / speed (yawRateUsed) in 1/10 000 m, "unavailable" below
  CURVATURE_MIN_SPEED_MPS where the ratio means nothing; saturated at +-1022 (release 2's out of range).
- low-frequency container (EN 302 637-2 6.1.3): in the first CAM and then in the first CAM generated
  LOW_FREQUENCY_INTERVAL_S or more after the last one that carried it (`LowFrequencyClock`); vehicleRole
  default, exteriorLights all off (the lights are not among what the host knows), pathHistory empty
  (allowed by the CDD's SIZE(0..40); the path history is a receiver's aid for map matching we do not need
  in the GCDC's lanes).
- Every confidence is "unavailable": our estimators do not publish one, and a made-up confidence would be
  worse than none.

The generation time on the air is GenerationDeltaTime, TimestampIts mod 65 536 ms: a receiver resolves it
against its receive time to the nearest instant (`resolve_generation_delta`), so a CAM's age is known only
modulo 65.536 s, and a frame replayed a multiple of 65.536 s later looks fresh. Only signatures with their
own generation time (IEEE 1609.2 / ETSI TS 103 097) fix that; they are outside this codec.

Received CAMs are read with the schema of their own protocolVersion (byte 0): 2 with v1.4.1, 1 with v1.3.2
(ITS-Container v1.2.1), both shipped (asn1/). A datagram must be exactly the canonical encoding of what it
decodes to (`codec.check_canonical`); a CAM whose high-frequency container is not a vehicle's is
NOT_A_VEHICLE; a value at a CDD "outOfRange" marker (release 2's speed 16382, acceleration +-160, yaw rate
+-32766, length 1022, width 61) is MALFORMED: no VehicleState carries it, and taken as a number it would
not encode again. The release-2 CAM (TS 103 900, CDD v2.4.1) is read from shared data only on request
(`EtsiCamSchema.CAM_2_3_1`): it reads the same protocolVersion-2 frames and takes ~2 s to compile.
"""

from __future__ import annotations

import functools
import math
import os
import time
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Any, Final

import asn1tools

from .codec import (
    ACCEL_OUT_OF_RANGE,
    ACCEL_UNAVAILABLE,
    CAM_PROTOCOL_VERSION,
    HEADING_UNAVAILABLE,
    LANE_POSITION_RANGE,
    LENGTH_OUT_OF_RANGE,
    LENGTH_UNAVAILABLE,
    MSG_CAM,
    SPEED_OUT_OF_RANGE,
    SPEED_UNAVAILABLE,
    WIDTH_OUT_OF_RANGE,
    WIDTH_UNAVAILABLE,
    YAW_RATE_OUT_OF_RANGE,
    DecodeReason,
    DriveDirection,
    V2xDecodeError,
    VehicleState,
    asn1_decode,
    asn1_encode,
    check_canonical,
    checked_integer,
    generation_delta,
    header_value,
    heading_from_etsi,
    heading_to_etsi_value,
    lat_from_etsi,
    lon_from_etsi,
    optional_integer,
    peek_header,
    position_to_etsi,
    resolve_generation_delta,
    scaled_from_etsi,
    scaled_to_etsi,
    yaw_rate_from_etsi,
    yaw_rate_to_etsi,
)
from .schemas import SchemaSet, compiled

# ---------------------------------------------------------------------------------------------- schemas


class EtsiCamSchema(StrEnum):
    CAM_1_3_2 = "cam-1.3.2"  # EN 302 637-2 v1.3.2 + ITS-Container 1.2.1: protocolVersion 1 (shipped)
    CAM_1_4_1 = "cam-1.4.1"  # EN 302 637-2 v1.4.1 + CDD TS 102 894-2 v1.3.1: protocolVersion 2 (shipped)
    CAM_2_3_1 = "cam-2.3.1"  # release 2, TS 103 900 v2.3.1 + CDD v2.4.1: protocolVersion 2 (shared data)


SHIPPED_SCHEMAS: Final = {
    EtsiCamSchema.CAM_1_3_2: SchemaSet.CAM_V1,
    EtsiCamSchema.CAM_1_4_1: SchemaSet.CAM_V2,
}
# The same sets as named in shared/data/v2x_asn1 (read in place with `directory`, never shipped from there).
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
SCHEMA_BY_PROTOCOL_VERSION: Final = {1: EtsiCamSchema.CAM_1_3_2, 2: EtsiCamSchema.CAM_1_4_1}
ETSI_ASN1_ENV: Final = "BYWIRE_ETSI_ASN1_DIR"


class EtsiSchemaMissing(FileNotFoundError):
    """The shared ETSI ASN.1 files are not where we looked; the message says where and what to set."""


def etsi_asn1_dir() -> Path:
    """Where the shared ETSI schemas are: $BYWIRE_ETSI_ASN1_DIR if set, else $BYWIRE_SHARED_DATA/v2x_asn1 if
    set, else shared/data/v2x_asn1 beside the checkout. Raises EtsiSchemaMissing naming every place tried."""
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
def _compiled_shared(schema: EtsiCamSchema, directory: Path) -> Any:
    files = [directory / name for name in ETSI_SCHEMA_FILES[schema]]
    for f in files:
        if not f.is_file():
            raise EtsiSchemaMissing(f"{schema.value}: {f} not found")
    return asn1tools.compile_files([str(f) for f in files], "uper")


def compiled_etsi_spec(schema: EtsiCamSchema, directory: Path | None = None) -> Any:
    """The schema set compiled for UPER: the shipped copy, or (directory given, release 2) the shared one."""
    schema = EtsiCamSchema(schema)
    if directory is None and schema in SHIPPED_SCHEMAS:
        return compiled(SHIPPED_SCHEMAS[schema])
    return _compiled_shared(schema, (directory or etsi_asn1_dir()).resolve())


# ---------------------------------------------------------------------------------------------- encoding

LOW_FREQUENCY_INTERVAL_S: Final = 0.5  # EN 302 637-2 6.1.3: LF container at most every 500 ms
CURVATURE_MIN_SPEED_MPS: Final = 1.0  # below, yaw rate / speed is noise over a near-zero divisor
CURVATURE_PER_M: Final = 10_000.0  # CDD v1.3.1 CurvatureValue: 1 / 10 000 m
CURVATURE_LIMIT: Final = 1022
CURVATURE_UNAVAILABLE: Final = 1023
_SEMI_AXIS_UNAVAILABLE = 4095
_ALTITUDE_UNAVAILABLE = 800_001
_SPEED_CONFIDENCE_UNAVAILABLE = 127
_HEADING_CONFIDENCE_UNAVAILABLE = 127
_ACCEL_CONFIDENCE_UNAVAILABLE = 102
# Earth radius for the small reference-point shift (<= 51 m): the local radius error is < 0.5 %.
_EARTH_RADIUS_M = 6_371_008.8


@dataclass
class LowFrequencyClock:
    """When a sender's next CAM carries the low-frequency container (EN 302 637-2 6.1.3)."""

    last_s: float = -math.inf

    def due(self, generation_time_s: float) -> bool:
        """True for the first CAM and for the first one LOW_FREQUENCY_INTERVAL_S after the last (marks it)."""
        if generation_time_s - self.last_s >= LOW_FREQUENCY_INTERVAL_S or generation_time_s < self.last_s:
            self.last_s = generation_time_s
            return True
        return False


def _shift_along(lat: float, lon: float, etsi_heading: int, distance_m: float) -> tuple[float, float]:
    """Move a point distance_m along an ETSI heading (0.1 deg clockwise from north); negative: backwards.
    The east step is scaled at the front point's latitude both ways, so that the shift back undoes the
    shift forward exactly (a re-encoded CAM is the same bytes)."""
    bearing = math.radians(etsi_heading / 10.0)
    north = distance_m * math.cos(bearing)
    east = distance_m * math.sin(bearing)
    dlat = math.degrees(north / _EARTH_RADIUS_M)
    front_lat = lat + dlat if distance_m >= 0.0 else lat
    dlon = math.degrees(east / (_EARTH_RADIUS_M * max(math.cos(math.radians(front_lat)), 1e-6)))
    return lat + dlat, lon + dlon


def _curvature(speed_value: int, yaw_rate_value: int) -> int:
    """CurvatureValue from the speed and yaw rate as sent (so that a received state encodes the same)."""
    v = scaled_from_etsi(speed_value, SPEED_UNAVAILABLE, 100.0)
    w = yaw_rate_from_etsi(yaw_rate_value)
    if v is None or w is None or v < CURVATURE_MIN_SPEED_MPS:
        return CURVATURE_UNAVAILABLE
    c = round(CURVATURE_PER_M * w / v)
    return max(-CURVATURE_LIMIT, min(CURVATURE_LIMIT, c))


def cam_value(state: VehicleState, *, low_frequency: bool) -> dict[str, Any]:
    """A VehicleState as the asn1tools value of a protocolVersion-2 CAM (V2xEncodeError names a bad field)."""
    o = "VehicleState"
    heading = heading_to_etsi_value(o, state.heading_rad)
    length = scaled_to_etsi(
        o, "length_m", state.length_m, 10.0, 1, LENGTH_OUT_OF_RANGE - 1, LENGTH_UNAVAILABLE, "m"
    )
    lat, lon = state.lat_deg, state.lon_deg
    if (
        lat is not None
        and lon is not None
        and heading != HEADING_UNAVAILABLE
        and length != LENGTH_UNAVAILABLE
    ):
        lat, lon = _shift_along(lat, lon, heading, 0.5 * length / 10.0)
        lat = min(90.0, max(-90.0, lat))  # a centre within 2.6 m of a pole; the range check names others
        lon = (lon + 180.0) % 360.0 - 180.0
    lat_n, lon_n = position_to_etsi(o, lat, lon)
    speed = scaled_to_etsi(
        o, "speed_mps", state.speed_mps, 100.0, 0, SPEED_OUT_OF_RANGE - 1, SPEED_UNAVAILABLE, "m/s"
    )
    yaw_rate = yaw_rate_to_etsi(o, state.yaw_rate_radps)
    curvature = _curvature(speed, yaw_rate)
    hf: dict[str, Any] = {
        "heading": {"headingValue": heading, "headingConfidence": _HEADING_CONFIDENCE_UNAVAILABLE},
        "speed": {"speedValue": speed, "speedConfidence": _SPEED_CONFIDENCE_UNAVAILABLE},
        "driveDirection": "unavailable"
        if state.drive_direction is None
        else DriveDirection(state.drive_direction).value,
        "vehicleLength": {
            "vehicleLengthValue": length,
            "vehicleLengthConfidenceIndication": "unavailable"
            if length == LENGTH_UNAVAILABLE
            else "noTrailerPresent",
        },
        "vehicleWidth": scaled_to_etsi(
            o, "width_m", state.width_m, 10.0, 1, WIDTH_OUT_OF_RANGE - 1, WIDTH_UNAVAILABLE, "m"
        ),
        "longitudinalAcceleration": {
            "longitudinalAccelerationValue": scaled_to_etsi(
                o,
                "accel_mps2",
                state.accel_mps2,
                10.0,
                -(ACCEL_OUT_OF_RANGE - 1),
                ACCEL_OUT_OF_RANGE - 1,
                ACCEL_UNAVAILABLE,
                "m/s^2",
            ),
            "longitudinalAccelerationConfidence": _ACCEL_CONFIDENCE_UNAVAILABLE,
        },
        "curvature": {"curvatureValue": curvature, "curvatureConfidence": "unavailable"},
        "curvatureCalculationMode": "unavailable" if curvature == CURVATURE_UNAVAILABLE else "yawRateUsed",
        "yawRate": {"yawRateValue": yaw_rate, "yawRateConfidence": "unavailable"},
    }
    lane = optional_integer(o, "lane_position", state.lane_position, LANE_POSITION_RANGE)
    if lane is not None:
        hf["lanePosition"] = lane
    params: dict[str, Any] = {
        "basicContainer": {
            "stationType": checked_integer(o, "station_type", state.station_type, 0, 255),
            "referencePosition": {
                "latitude": lat_n,
                "longitude": lon_n,
                "positionConfidenceEllipse": {
                    "semiMajorConfidence": _SEMI_AXIS_UNAVAILABLE,
                    "semiMinorConfidence": _SEMI_AXIS_UNAVAILABLE,
                    "semiMajorOrientation": HEADING_UNAVAILABLE,
                },
                "altitude": {"altitudeValue": _ALTITUDE_UNAVAILABLE, "altitudeConfidence": "unavailable"},
            },
        },
        "highFrequencyContainer": ("basicVehicleContainerHighFrequency", hf),
    }
    if low_frequency:
        params["lowFrequencyContainer"] = (
            "basicVehicleContainerLowFrequency",
            {"vehicleRole": "default", "exteriorLights": (b"\x00", 8), "pathHistory": []},
        )
    return {
        "header": header_value(MSG_CAM, CAM_PROTOCOL_VERSION, o, state.station_id),
        "cam": {"generationDeltaTime": generation_delta(o, state.generation_time_s), "camParameters": params},
    }


def encode_cam_value(value: dict[str, Any]) -> bytes:
    """An asn1tools CAM value (protocolVersion 2) -> UPER bytes."""
    return asn1_encode(compiled(SchemaSet.CAM_V2), "CAM", value, "CAM", fast=True)


def encode_cam(state: VehicleState, *, low_frequency: bool = True) -> bytes:
    """A VehicleState -> the CAM we broadcast (low_frequency: with the LF container, LowFrequencyClock)."""
    return encode_cam_value(cam_value(state, low_frequency=low_frequency))


# ---------------------------------------------------------------------------------------------- decoding


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
    value = asn1_decode(
        compiled_etsi_spec(schema, directory), "CAM", frame, f"CAM ({schema.value})", fast=True
    )
    return schema, value


def _field(d: dict[str, Any], *names: str) -> Any:
    """The first of `names` present in d: release 2 renamed fields (messageID -> messageId, ...)."""
    for n in names:
        if n in d:
            return d[n]
    raise KeyError("/".join(names))


_OUT_OF_RANGE_MARKERS: Final = (
    ("speed", (SPEED_OUT_OF_RANGE,)),
    ("longitudinalAcceleration", (ACCEL_OUT_OF_RANGE, -ACCEL_OUT_OF_RANGE)),
    ("yawRate", (YAW_RATE_OUT_OF_RANGE, -YAW_RATE_OUT_OF_RANGE)),
    ("vehicleLength", (LENGTH_OUT_OF_RANGE,)),
    ("vehicleWidth", (WIDTH_OUT_OF_RANGE,)),
)


def _refuse_out_of_range_markers(what: str, values: dict[str, int]) -> None:
    for name, markers in _OUT_OF_RANGE_MARKERS:
        if values[name] in markers:
            raise V2xDecodeError(
                DecodeReason.MALFORMED, f"{what}: {name} {values[name]} is the CDD out-of-range marker"
            )


def from_etsi_cam(
    frame_bytes: bytes,
    reference_time_s: float | None = None,
    *,
    schema: EtsiCamSchema | None = None,
    directory: Path | None = None,
    check_message_id: bool = True,
    canonical: bool = True,
) -> VehicleState:
    """An ETSI CAM (UPER) -> VehicleState, the schema chosen by its protocolVersion (byte 0).

    reference_time_s resolves the 65.536 s wrap of GenerationDeltaTime (the receive time; None: now, read
    from the wall clock here at the edge). The position is moved from the ETSI reference point to the
    vehicle centre when heading and length are known. A CAM from a road-side unit (no basic vehicle
    high-frequency container) raises V2xDecodeError(NOT_A_VEHICLE); check_message_id=False accepts a
    header messageID other than cam(2) (asn1tools' test vectors); canonical=False skips the re-encoding
    check (a tool reading frames of other stacks).
    """
    frame_bytes = bytes(frame_bytes)
    used, cam = decode_etsi_cam(frame_bytes, schema, directory)
    what = f"CAM ({used.value})"
    try:
        header = cam["header"]
        message_id = _field(header, "messageID", "messageId")
        if check_message_id and message_id != MSG_CAM:
            raise V2xDecodeError(
                DecodeReason.UNKNOWN_MESSAGE, f"{what}: header messageID {message_id}, a CAM has {MSG_CAM}"
            )
        station_id = _field(header, "stationID", "stationId")
        params = cam["cam"]["camParameters"]
        choice, hf = params["highFrequencyContainer"]
        if choice != "basicVehicleContainerHighFrequency":
            raise V2xDecodeError(DecodeReason.NOT_A_VEHICLE, f"{what}: high-frequency container is {choice}")
        basic = params["basicContainer"]
        ref = basic["referencePosition"]
        lat, lon = lat_from_etsi(ref["latitude"]), lon_from_etsi(ref["longitude"])
        heading = hf["heading"]["headingValue"]
        length = hf["vehicleLength"]["vehicleLengthValue"]
        accel = _field(hf["longitudinalAcceleration"], "longitudinalAccelerationValue", "value")
        _refuse_out_of_range_markers(
            what,
            {
                "speed": hf["speed"]["speedValue"],
                "longitudinalAcceleration": accel,
                "yawRate": hf["yawRate"]["yawRateValue"],
                "vehicleLength": length,
                "vehicleWidth": hf["vehicleWidth"],
            },
        )
        if canonical:
            check_canonical(compiled_etsi_spec(used, directory), "CAM", cam, frame_bytes, what, fast=True)
        length_m = scaled_from_etsi(length, LENGTH_UNAVAILABLE, 10.0)
        if lat is not None and lon is not None and heading != HEADING_UNAVAILABLE and length_m is not None:
            lat, lon = _shift_along(lat, lon, heading, -0.5 * length_m)
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
            station_type=basic["stationType"],
        )
    except V2xDecodeError:
        raise
    except (KeyError, TypeError, ValueError) as e:
        raise V2xDecodeError(DecodeReason.DECODER_FAULT, f"{what}: {type(e).__name__}: {e}") from None

"""The GCDC 2016 iCLCM (iGAME Cooperative Lane Change Message v1.0) to and from `CooperativeState`.

The 2016 Grand Cooperative Driving Challenge sent, beside each vehicle's CAM, what a cooperative
controller needs beyond it: the iCLCM (messageID 10, protocolVersion 1, asn1/iCLCM.asn). We send ours
beside our CAM at the same rate (host `V2vTxIo`); the receiver takes others' through the same hardening.

What our platoon (seed 003 V-C, V-D; host/modules/control/platoon.py) knows, in iCLCM fields:

- targetLongitudinalAcceleration (0.01 m/s^2, +-10): the acceleration our controller requests of the ECU
  (`/control/request`), the feed-forward a CACC follower adds.
- controllerType: cacc while the platoon controller drives, manual otherwise.
- timeHeadway (0.1 s): the platoon's time gap (the GCDC's 0.6 s).
- cruiseSpeed (0.01 m/s): the mission's set speed.
- vehicleRearAxleLocation (0.01 m): front bumper (the CAM's reference point) to the rear axle.
- vehicleResponseTime (0.01 s): time constant and dead time of our acceleration response (None:
  unavailable).
- mostImportantObject: the lead we follow: its station id, gap (0.01 m), bearing (1/500 rad, positive to
  the right on the air; 0 straight ahead), gap rate (0.01 m/s).
- scenarioObject.platoonID: our platoon (1 A, 2 B, 3 not used; 0 none).
- lane, pairIdObject, mergeObject, distanceTravelledCZ, intention, counterIntersection and the
  low-frequency flags belong to the GCDC 2016 merge and intersection scenarios, which our platoon does not
  drive: sent as lane unavailable, ids 0, flags 0, straight on.

The low-frequency container is sent only when one of its three flags is set (all OPTIONAL). Generation
time: GenerationDeltaTime as in a CAM (TimestampIts mod 65536, resolved against the receive time).
The MIO bearing's sense is the GCDC's (positive to the right); in SI here it is radians counter-clockwise
(positive to the left), converted at this edge. Strict decoding as for CAMs: canonical bytes only.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from enum import IntEnum
from typing import Any, Final

from .codec import (
    ICLCM_PROTOCOL_VERSION,
    MSG_ICLCM,
    STATION_ID_MAX,
    DecodeReason,
    V2xDecodeError,
    asn1_decode,
    asn1_encode,
    check_canonical,
    checked_integer,
    generation_delta,
    header_value,
    resolve_generation_delta,
    scaled_from_etsi,
    scaled_to_etsi,
)
from .schemas import SchemaSet, compiled

TYPE_NAME: Final = "IGAMECooperativeLaneChangeMessage"
TARGET_ACCEL_UNAVAILABLE: Final = 1001
TIME_HEADWAY_UNAVAILABLE: Final = 361
CRUISE_SPEED_UNAVAILABLE: Final = 5001
RESPONSE_TIME_UNAVAILABLE: Final = 1001
MIO_RANGE_UNAVAILABLE: Final = 65_535
MIO_BEARING_UNAVAILABLE: Final = 1572
MIO_RANGE_RATE_UNAVAILABLE: Final = 32_767
LANE_UNAVAILABLE: Final = 4
MIO_BEARING_PER_RAD: Final = 500.0


class ControllerType(IntEnum):
    MANUAL = 0
    CC = 1
    ACC = 2
    CACC = 3


class Intention(IntEnum):
    STRAIGHT = 1
    TURN_LEFT = 2
    TURN_RIGHT = 3


@dataclass(frozen=True, slots=True)
class CooperativeState:
    """What one vehicle's cooperative controller says beyond its CAM (an iCLCM), in SI. None: unavailable."""

    station_id: int
    generation_time_s: float
    controller_type: ControllerType = ControllerType.MANUAL
    target_accel_mps2: float | None = None
    time_headway_s: float | None = None
    cruise_speed_mps: float | None = None
    rear_axle_m: float = 0.0  # front bumper to rear axle
    response_time_constant_s: float | None = None
    response_time_delay_s: float | None = None
    mio_station_id: int = 0  # 0: no most important object
    mio_range_m: float | None = None
    mio_bearing_rad: float | None = None  # counter-clockwise positive (to the left)
    mio_range_rate_mps: float | None = None
    lane: int | None = None  # GCDC lane 1..3
    platoon_id: int = 0
    forward_id: int = 0
    backward_id: int = 0
    acknowledge: bool = False
    merge_request: bool = False
    safe_to_merge: bool = False
    merge_ready: bool = False
    last_vehicle: bool = False
    first_vehicle: bool = False
    distance_travelled_cz_m: float = 0.0
    intention: Intention = Intention.STRAIGHT
    counter_intersection: int = 0
    participants_ready: bool | None = None
    start_platoon: int | None = None  # 0: platoon A at 80 km/h, 1: platoon B at 60 km/h
    end_of_scenario: bool = False


def _flag(value: bool) -> int:
    return 1 if value else 0


def iclcm_value(msg: CooperativeState) -> dict[str, Any]:
    """A CooperativeState as the asn1tools value of an iCLCM (V2xEncodeError names a bad field)."""
    o = "CooperativeState"

    def ids(name: str, v: int) -> int:
        return checked_integer(o, name, v, 0, STATION_ID_MAX)

    bearing = msg.mio_bearing_rad
    hf = {
        "vehicleRearAxleLocation": scaled_to_etsi(o, "rear_axle_m", msg.rear_axle_m, 100.0, 0, 4095, -1, "m"),
        "controllerType": int(ControllerType(msg.controller_type)),
        "vehicleResponseTime": {
            "vehicleResponseTimeConstant": scaled_to_etsi(
                o, "response_time_constant_s", msg.response_time_constant_s, 100.0, 0, 1000,
                RESPONSE_TIME_UNAVAILABLE, "s",
            ),
            "vehicleResponseTimeDelay": scaled_to_etsi(
                o, "response_time_delay_s", msg.response_time_delay_s, 100.0, 0, 1000,
                RESPONSE_TIME_UNAVAILABLE, "s",
            ),
        },
        "targetLongitudinalAcceleration": scaled_to_etsi(
            o, "target_accel_mps2", msg.target_accel_mps2, 100.0, -1000, 1000,
            TARGET_ACCEL_UNAVAILABLE, "m/s^2",
        ),
        "timeHeadway": scaled_to_etsi(
            o, "time_headway_s", msg.time_headway_s, 10.0, 0, 360, TIME_HEADWAY_UNAVAILABLE, "s"
        ),
        "cruiseSpeed": scaled_to_etsi(
            o, "cruise_speed_mps", msg.cruise_speed_mps, 100.0, 0, 5000, CRUISE_SPEED_UNAVAILABLE, "m/s"
        ),
    }  # fmt: skip
    params: dict[str, Any] = {
        "vehicleContainerHighFrequency": hf,
        "mostImportantObjectContainer": {
            "mioID": ids("mio_station_id", msg.mio_station_id),
            "mioRange": scaled_to_etsi(
                o, "mio_range_m", msg.mio_range_m, 100.0, 0, 65_534, MIO_RANGE_UNAVAILABLE, "m"
            ),
            # GCDC: positive to the right; ours: counter-clockwise
            "mioBearing": scaled_to_etsi(
                o, "mio_bearing_rad", None if bearing is None else -bearing, MIO_BEARING_PER_RAD, -1571, 1571,
                MIO_BEARING_UNAVAILABLE, "rad",
            ),
            "mioRangeRate": scaled_to_etsi(
                o, "mio_range_rate_mps", msg.mio_range_rate_mps, 100.0, -32_767, 32_766,
                MIO_RANGE_RATE_UNAVAILABLE, "m/s",
            ),
        },
        "laneObject": {
            "lane": LANE_UNAVAILABLE if msg.lane is None else checked_integer(o, "lane", msg.lane, 1, 3)
        },
        "pairIdObject": {
            "forwardID": ids("forward_id", msg.forward_id),
            "backwardID": ids("backward_id", msg.backward_id),
            "acknowledgeFlag": _flag(msg.acknowledge),
        },
        "mergeObject": {
            "mergeRequest": _flag(msg.merge_request),
            "mergeSafeToMerge": _flag(msg.safe_to_merge),
            "mergeFlag": _flag(msg.merge_ready),
            "mergeFlagTail": _flag(msg.last_vehicle),
            "mergeFlagHead": _flag(msg.first_vehicle),
        },
        "scenarioObject": {
            "platoonID": checked_integer(o, "platoon_id", msg.platoon_id, 0, 255),
            "distanceTravelledCZ": scaled_to_etsi(
                o, "distance_travelled_cz_m", msg.distance_travelled_cz_m, 10.0, 0, 10_000, -1, "m"
            ),
            "intention": int(Intention(msg.intention)),
            "counterIntersection": checked_integer(o, "counter_intersection", msg.counter_intersection, 0, 3),
        },
    }  # fmt: skip
    low: dict[str, int] = {}
    if msg.participants_ready is not None:
        low["participantsReady"] = _flag(msg.participants_ready)
    if msg.start_platoon is not None:
        low["startPlatoon"] = checked_integer(o, "start_platoon", msg.start_platoon, 0, 1)
    if msg.end_of_scenario:
        low["endOfScenario"] = 1
    if low:
        params["vehicleContainerLowFrequency"] = low
    return {
        "itsHeader": header_value(MSG_ICLCM, ICLCM_PROTOCOL_VERSION, o, msg.station_id),
        "iclcm": {
            "generationDeltaTime": generation_delta(o, msg.generation_time_s),
            "iclcmParameters": params,
        },
    }


def encode_iclcm(msg: CooperativeState) -> bytes:
    """A CooperativeState -> the iCLCM we broadcast."""
    return asn1_encode(compiled(SchemaSet.ICLCM), TYPE_NAME, iclcm_value(msg), "iCLCM", fast=True)


def decode_iclcm(data: bytes, reference_time_s: float | None = None) -> CooperativeState:
    """An iCLCM -> CooperativeState (reference_time_s resolves GenerationDeltaTime; None: now)."""
    data = bytes(data)
    spec = compiled(SchemaSet.ICLCM)
    value = asn1_decode(spec, TYPE_NAME, data, "iCLCM", fast=True)
    try:
        header = value["itsHeader"]
        if header["messageID"] != MSG_ICLCM or header["protocolVersion"] != ICLCM_PROTOCOL_VERSION:
            raise V2xDecodeError(
                DecodeReason.UNKNOWN_MESSAGE,
                f"iCLCM: header messageID {header['messageID']}, protocolVersion {header['protocolVersion']}",
            )
        check_canonical(spec, TYPE_NAME, value, data, "iCLCM", fast=True)
        body = value["iclcm"]
        p = body["iclcmParameters"]
        hf = p["vehicleContainerHighFrequency"]
        rt = hf["vehicleResponseTime"]
        mio = p["mostImportantObjectContainer"]
        pair = p["pairIdObject"]
        merge = p["mergeObject"]
        scen = p["scenarioObject"]
        low = p.get("vehicleContainerLowFrequency", {})
        bearing = scaled_from_etsi(mio["mioBearing"], MIO_BEARING_UNAVAILABLE, MIO_BEARING_PER_RAD)
        ready = low.get("participantsReady")
        lane = p["laneObject"]["lane"]
        t_ref = time.time() if reference_time_s is None else reference_time_s
        return CooperativeState(
            station_id=header["stationID"],
            generation_time_s=resolve_generation_delta(body["generationDeltaTime"], t_ref),
            controller_type=ControllerType(hf["controllerType"]),
            target_accel_mps2=scaled_from_etsi(
                hf["targetLongitudinalAcceleration"], TARGET_ACCEL_UNAVAILABLE, 100.0
            ),
            time_headway_s=scaled_from_etsi(hf["timeHeadway"], TIME_HEADWAY_UNAVAILABLE, 10.0),
            cruise_speed_mps=scaled_from_etsi(hf["cruiseSpeed"], CRUISE_SPEED_UNAVAILABLE, 100.0),
            rear_axle_m=hf["vehicleRearAxleLocation"] / 100.0,
            response_time_constant_s=scaled_from_etsi(
                rt["vehicleResponseTimeConstant"], RESPONSE_TIME_UNAVAILABLE, 100.0
            ),
            response_time_delay_s=scaled_from_etsi(
                rt["vehicleResponseTimeDelay"], RESPONSE_TIME_UNAVAILABLE, 100.0
            ),
            mio_station_id=mio["mioID"],
            mio_range_m=scaled_from_etsi(mio["mioRange"], MIO_RANGE_UNAVAILABLE, 100.0),
            mio_bearing_rad=None if bearing is None else 0.0 - bearing,
            mio_range_rate_mps=scaled_from_etsi(mio["mioRangeRate"], MIO_RANGE_RATE_UNAVAILABLE, 100.0),
            lane=None if lane == LANE_UNAVAILABLE else lane,
            platoon_id=scen["platoonID"],
            forward_id=pair["forwardID"],
            backward_id=pair["backwardID"],
            acknowledge=bool(pair["acknowledgeFlag"]),
            merge_request=bool(merge["mergeRequest"]),
            safe_to_merge=bool(merge["mergeSafeToMerge"]),
            merge_ready=bool(merge["mergeFlag"]),
            last_vehicle=bool(merge["mergeFlagTail"]),
            first_vehicle=bool(merge["mergeFlagHead"]),
            distance_travelled_cz_m=scen["distanceTravelledCZ"] / 10.0,
            intention=Intention(scen["intention"]),
            counter_intersection=scen["counterIntersection"],
            participants_ready=None if ready is None else bool(ready),
            start_platoon=low.get("startPlatoon"),
            end_of_scenario="endOfScenario" in low,
        )
    except V2xDecodeError:
        raise
    except (KeyError, TypeError, ValueError) as e:
        raise V2xDecodeError(DecodeReason.DECODER_FAULT, f"iCLCM: {type(e).__name__}: {e}") from None

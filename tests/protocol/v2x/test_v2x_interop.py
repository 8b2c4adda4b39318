"""What we send, read by another stack: an asn1tools compilation of the shared schemas (../shared/data/
v2x_asn1, read in place, compiled here independently of the copies we ship) decodes our CAM, iCLCM,
SPATEM and MAPEM into the values we meant, in the standards' units."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import asn1tools
import pytest
from shared_data import shared_data_dir

from bywire.protocol.v2x.codec import (
    DriveDirection,
    SpeedLimit,
    TrafficLightPhase,
    VehicleState,
    unix_to_timestamp_its,
)
from bywire.protocol.v2x.dsrc import IntersectionMap, RoadMap, SignalGroupState, SignalPhases, StopLine
from bywire.protocol.v2x.iclcm import ControllerType, CooperativeState
from bywire.protocol.v2x.wire import encode

DATA_DIR = shared_data_dir() / "v2x_asn1"
T0_S = 1_700_000_000.0

pytestmark = pytest.mark.skipif(
    not (DATA_DIR / "SOURCES.md").is_file(), reason=f"shared V2X schemas not found at {DATA_DIR}"
)

# What ISO TS 19091's DSRC imports and the shared folder lacks (its region profile, ISO 24534-3's vehicle
# type), and the TS 103 301 SPATEM wrapper: written here from the standards, as a stack would.
DSRC_SIDE_MODULES = (
    """
REGION { iso (1) standard (0) signalizedIntersection (19091) profilec(2) region (1) version2 (2) }
DEFINITIONS AUTOMATIC TAGS ::= BEGIN
IMPORTS REG-EXT-ID-AND-TYPE FROM DSRC { iso (1) standard (0) signalizedIntersection (19091) profilec(2)
  dsrc (2) version2 (2) };
"""
    + "\n".join(
        f"Reg-{name} REG-EXT-ID-AND-TYPE ::= {{ ... }}"
        for name in [
            "AdvisorySpeed",
            "ComputedLane",
            "ConnectionManeuverAssist",
            "GenericLane",
            "IntersectionGeometry",
            "IntersectionState",
            "LaneAttributes",
            "LaneDataAttribute",
            "MapData",
            "MovementEvent",
            "MovementState",
            "NodeAttributeSetXY",
            "NodeOffsetPointXY",
            "Position3D",
            "RequestorDescription",
            "RequestorType",
            "RestrictionUserType",
            "RoadSegment",
            "RTCMcorrections",
            "SignalControlZone",
            "SignalRequestPackage",
            "SignalRequest",
            "SignalStatus",
            "SignalStatusPackage",
            "SignalRequestMessage",
            "SignalStatusMessage",
            "SPAT",
        ]
    )
    + """
END
ElectronicRegistrationIdentificationVehicleDataModule { iso(1) standard(0) iso24534 (24534) vehicleData (1)
  version1 (1) }
DEFINITIONS AUTOMATIC TAGS ::= BEGIN
Iso3833VehicleType ::= INTEGER (0..255)
END
SPATEM-PDU-Descriptions { itu-t (0) identified-organization (4) etsi (0) itsDomain (5) wg1 (1)
  ts103301 (103301) spatem (0) version2 (2) }
DEFINITIONS AUTOMATIC TAGS ::= BEGIN
IMPORTS SPAT FROM DSRC { iso (1) standard (0) signalizedIntersection (19091) profilec(2) dsrc (2)
  version2 (2) }
ItsPduHeader FROM ITS-Container { itu-t (0) identified-organization (4) etsi (0) itsDomain (5) wg1 (1)
  ts (102894) cdd (2) version (2) };
SPATEM ::= SEQUENCE { header ItsPduHeader, spat SPAT }
END
"""
)


def _compile(*names: str, extra: str = "") -> Any:
    files = [str(DATA_DIR / n) for n in names]
    if not extra:
        return asn1tools.compile_files(files, "uper")
    text = "\n".join(Path(f).read_text() for f in files) + extra
    return asn1tools.compile_string(text, "uper")


@pytest.fixture(scope="module")
def cam_v141() -> Any:
    return _compile("vanetza__EN302637-2v141-CAM.asn", "vanetza__TS102894-2v131-CDD.asn")


def _state() -> VehicleState:
    return VehicleState(
        station_id=4711,
        generation_time_s=T0_S + 0.123,
        lat_deg=49.0123456,
        lon_deg=8.4123456,
        heading_rad=0.3,
        speed_mps=25.0,
        yaw_rate_radps=0.05,
        accel_mps2=-1.2,
        length_m=4.8,
        width_m=1.8,
        drive_direction=DriveDirection.FORWARD,
        lane_position=2,
    )


def _check_cam(cam: dict[str, Any]) -> None:
    header = cam["header"]
    assert (
        header.get("messageID", header.get("messageId")),
        header.get("stationID", header.get("stationId")),
    ) == (
        2,
        4711,
    )
    assert cam["cam"]["generationDeltaTime"] == unix_to_timestamp_its(T0_S + 0.123) % 65536
    params = cam["cam"]["camParameters"]
    kind, hf = params["highFrequencyContainer"]
    assert kind == "basicVehicleContainerHighFrequency"
    assert hf["speed"]["speedValue"] == 2500  # 0.01 m/s
    assert hf["heading"]["headingValue"] == round((90.0 - math.degrees(0.3)) * 10)  # 0.1 deg from north
    assert hf["yawRate"]["yawRateValue"] == round(math.degrees(0.05) * 100)  # 0.01 deg/s
    accel = hf["longitudinalAcceleration"]
    assert accel.get("longitudinalAccelerationValue", accel.get("value")) == -12  # 0.1 m/s^2
    assert hf["vehicleLength"]["vehicleLengthValue"] == 48 and hf["vehicleWidth"] == 18
    assert hf["driveDirection"] == "forward" and hf["lanePosition"] == 2
    ref = params["basicContainer"]["referencePosition"]
    # the front reference point: 2.4 m ahead of the centre along the heading
    assert (ref["latitude"] / 1e7 - 49.0123456) * 111_195.0 == pytest.approx(2.4 * math.sin(0.3), abs=0.02)
    assert params["lowFrequencyContainer"][0] == "basicVehicleContainerLowFrequency"


def test_our_cam_decodes_with_the_etsi_v141_schema(cam_v141: Any) -> None:
    data = encode(_state())
    _check_cam(cam_v141.decode("CAM", data, check_constraints=True))
    # and the other stack's encoding of that value is our bytes
    assert bytes(cam_v141.encode("CAM", cam_v141.decode("CAM", data))) == data


def test_our_cam_decodes_with_the_release_2_schema() -> None:
    spec = _compile("vanetza__release2__TS103900v231-CAM.asn", "vanetza__release2__TS102894-2v241-CDD.asn")
    _check_cam(spec.decode("CAM", encode(_state()), check_constraints=True))


def test_our_iclcm_decodes_with_the_gcdc_schema() -> None:
    spec = _compile("gcdc2016_iCLCM_v1.0.asn1")
    msg = CooperativeState(
        4711, T0_S + 0.5, ControllerType.CACC, -2.34, 0.6, 22.22, 3.66, None, 0.1, 8, 17.5, 0.0, -0.75,
        platoon_id=1, end_of_scenario=True,
    )  # fmt: skip
    value = spec.decode("IGAMECooperativeLaneChangeMessage", encode(msg), check_constraints=True)
    assert value["itsHeader"] == {"protocolVersion": 1, "messageID": 10, "stationID": 4711}
    body = value["iclcm"]
    assert body["generationDeltaTime"] == unix_to_timestamp_its(T0_S + 0.5) % 65536
    p = body["iclcmParameters"]
    assert p["vehicleContainerHighFrequency"] == {
        "vehicleRearAxleLocation": 366,
        "controllerType": 3,
        "vehicleResponseTime": {"vehicleResponseTimeConstant": 1001, "vehicleResponseTimeDelay": 10},
        "targetLongitudinalAcceleration": -234,
        "timeHeadway": 6,
        "cruiseSpeed": 2222,
    }
    assert p["mostImportantObjectContainer"] == {
        "mioID": 8,
        "mioRange": 1750,
        "mioBearing": 0,
        "mioRangeRate": -75,
    }
    assert p["laneObject"] == {"lane": 4}
    assert p["scenarioObject"]["platoonID"] == 1
    assert p["vehicleContainerLowFrequency"] == {"endOfScenario": 1}


@pytest.fixture(scope="module")
def dsrc() -> Any:
    return _compile(
        "asn1tools__etsi__mapem_2_1_1.asn",
        "asn1tools__cen__dsrc.asn",
        "vanetza__TS102894-2v131-CDD.asn",
        extra=DSRC_SIDE_MODULES,
    )


def test_our_spatem_decodes_with_the_dsrc_schema(dsrc: Any) -> None:
    t = T0_S + 0.25
    group = SignalGroupState(1234, 5, TrafficLightPhase.RED, 12.3)
    value = dsrc.decode("SPATEM", encode(SignalPhases(99, t, (group,))), check_constraints=True)
    assert value["header"] == {"protocolVersion": 2, "messageID": 4, "stationID": 99}
    (state,) = value["spat"]["intersections"]
    assert state["id"] == {"id": 1234}
    assert state["moy"] * 60 + state["timeStamp"] / 1000 == pytest.approx(t - 1_672_531_200, abs=1e-3)  # 2023
    (movement,) = state["states"]
    assert movement["signalGroup"] == 5
    (event,) = movement["state-time-speed"]
    assert event["eventState"] == "stop-And-Remain"
    assert event["timing"]["minEndTime"] == round((t % 3600 + 12.3) * 10)  # 0.1 s in the hour


def test_our_mapem_decodes_with_the_mapem_schema(dsrc: Any) -> None:
    line = StopLine(5, 49.01, 8.41, 0.0)  # traffic heading east
    zone = SpeedLimit(99, T0_S, 77, 49.02, 8.42, 50 / 3.6, math.pi / 2)
    msg = RoadMap(99, T0_S, (IntersectionMap(1234, (line,)),), (zone,))
    value = dsrc.decode("MAPEM", encode(msg), check_constraints=True)
    assert value["header"] == {"protocolVersion": 2, "messageID": 5, "stationID": 99}
    m = value["map"]
    (g,) = m["intersections"]
    assert g["id"] == {"id": 1234} and g["refPoint"] == {"lat": 490_100_000, "long": 84_100_000}
    ingress = next(lane for lane in g["laneSet"] if lane["connectsTo"][0]["signalGroup"] == 5)
    nodes = ingress["nodeList"][1]
    assert nodes[0]["delta"] == ("node-XY6", {"x": 0, "y": 0})  # the stop line
    assert nodes[1]["delta"] == ("node-XY6", {"x": -1000, "y": 0})  # 10 m upstream (west), in cm
    (seg,) = m["roadSegments"]
    assert seg["id"] == {"id": 77}
    assert seg["speedLimits"] == [{"type": "vehicleMaxSpeed", "speed": round(50 / 3.6 / 0.02)}]  # 0.02 m/s

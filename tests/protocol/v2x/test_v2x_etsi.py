"""Real ETSI CAM frames off the air (cooperative driving), decoded with the schema of their protocolVersion
(the shipped copies, and the shared ones read in place from ../shared/data/v2x_asn1) into our VehicleState,
and taken by the receiver."""

from __future__ import annotations

import base64
import json
import math
from pathlib import Path
from typing import Any

import pytest
from shared_data import shared_data_dir

from bywire.protocol.v2x.codec import (
    DecodeReason,
    DriveDirection,
    V2xDecodeError,
    VehicleState,
    unix_to_timestamp_its,
)
from bywire.protocol.v2x.etsi_cam import (
    EtsiCamSchema,
    EtsiSchemaMissing,
    compiled_etsi_spec,
    decode_etsi_cam,
    etsi_asn1_dir,
    from_etsi_cam,
)
from bywire.protocol.v2x.receiver import GeoPoint, V2vReceiver, haversine_m
from bywire.protocol.v2x.wire import decode, encode

DATA_DIR = shared_data_dir() / "v2x_asn1"
REAL = DATA_DIR / "cam_uper_real_vectors_from_issue_threads.json"
TEST_VECTORS = DATA_DIR / "cam_uper_test_vectors_from_asn1tools.json"
T0_S = 1_700_000_000.0

pytestmark = pytest.mark.skipif(
    not REAL.is_file(), reason=f"ETSI V2X data (CAM schemas and frames) not found at {DATA_DIR}"
)


def _frames(path: Path) -> dict[str, bytes]:
    doc: dict[str, Any] = json.loads(path.read_text())
    out = {}
    for v in doc["vectors"]:
        out[v["name"]] = bytes.fromhex(v["hex"]) if "hex" in v else base64.b64decode(v["base64"])
    return out


@pytest.fixture(scope="module")
def real() -> dict[str, bytes]:
    return _frames(REAL)


def test_protocol_version_2_cam_off_the_air(real: dict[str, bytes]) -> None:
    frame = real["pycrate_issue_156"]
    assert frame[0] == 2
    v = from_etsi_cam(frame, T0_S)
    assert from_etsi_cam(frame, T0_S, directory=DATA_DIR) == v  # the shipped schema is the shared one
    assert v.station_id == 55552
    assert v.speed_mps == 0.0
    assert v.width_m == 1.8 and v.length_m == 4.4
    assert v.accel_mps2 == 0.0 and v.yaw_rate_radps == 0.0
    assert v.drive_direction is None  # "unavailable"
    assert v.heading_rad == pytest.approx(math.pi / 2 - math.radians(157.0))
    # The ETSI reference point (front centre) 42.1280170 N, -8.6227780 E, moved back half the 4.4 m length
    # along the heading (157 deg, so the centre lies towards 337 deg) to the geometric centre.
    assert v.lat_deg is not None and v.lon_deg is not None
    assert haversine_m(42.1280170, -8.6227780, v.lat_deg, v.lon_deg) == pytest.approx(2.2, abs=0.01)
    north_m = (v.lat_deg - 42.1280170) * 111_195.0
    assert north_m == pytest.approx(-2.2 * math.cos(math.radians(157.0)), abs=0.02)
    # GenerationDeltaTime 45543, resolved to the TimestampIts nearest the reference time.
    assert unix_to_timestamp_its(v.generation_time_s) % 65536 == 45543
    assert abs(v.generation_time_s - T0_S) <= 32.768


def test_protocol_version_1_cam_off_the_air(real: dict[str, bytes]) -> None:
    frame = real["vanetza_issue_201"]
    assert frame[0] == 1
    v = from_etsi_cam(frame, T0_S)
    assert from_etsi_cam(frame, T0_S, directory=DATA_DIR) == v
    assert v.station_id == 78880133
    assert v.speed_mps == 6.67
    assert v.drive_direction is DriveDirection.FORWARD
    # Length unavailable: the reference point stays as sent.
    assert (v.lat_deg, v.lon_deg) == (52.1697576, 5.3903308)
    assert v.length_m is None and v.width_m is None
    assert v.yaw_rate_radps is None and v.accel_mps2 is None
    assert v.heading_rad == pytest.approx(math.pi / 2 - math.radians(337.0) + 2 * math.pi)


def test_schema_is_chosen_by_protocol_version(real: dict[str, bytes]) -> None:
    v2, v1 = real["pycrate_issue_156"], real["vanetza_issue_201"]
    assert decode_etsi_cam(v2)[0] is EtsiCamSchema.CAM_1_4_1
    assert decode_etsi_cam(v1)[0] is EtsiCamSchema.CAM_1_3_2
    # The other version's schema fails on each (at curvatureCalculationMode, as SOURCES.md says).
    for frame, wrong in (
        (v2, EtsiCamSchema.CAM_1_3_2),
        (v1, EtsiCamSchema.CAM_2_3_1),
        (v1, EtsiCamSchema.CAM_1_4_1),
    ):
        with pytest.raises(V2xDecodeError) as err:
            from_etsi_cam(
                frame, T0_S, schema=wrong, directory=DATA_DIR if wrong is EtsiCamSchema.CAM_2_3_1 else None
            )
        assert err.value.reason is DecodeReason.MALFORMED
        assert "curvatureCalculation" in str(err.value)
    # Release 2 (CAM 2.3.1 + CDD 2.4.1, shared data only) reads the protocolVersion-2 frame to the same state.
    assert from_etsi_cam(v2, T0_S, schema=EtsiCamSchema.CAM_2_3_1, directory=DATA_DIR) == from_etsi_cam(
        v2, T0_S
    )
    with pytest.raises(V2xDecodeError) as err:
        from_etsi_cam(bytes([7]) + v2[1:], T0_S)
    assert err.value.reason is DecodeReason.BAD_VERSION


def test_asn1tools_boundary_vectors_with_the_1_3_2_schema() -> None:
    frames = _frames(TEST_VECTORS)
    m1 = frames["message1_basicVehicleHF"]
    # Header messageID 1 (denm): not a CAM unless told to ignore it.
    with pytest.raises(V2xDecodeError) as err:
        from_etsi_cam(m1, T0_S)
    assert err.value.reason is DecodeReason.UNKNOWN_MESSAGE
    v = from_etsi_cam(m1, T0_S, schema=EtsiCamSchema.CAM_1_3_2, check_message_id=False)
    assert v.station_id == 2**32 - 1
    assert v.lat_deg == -90.0 and v.lon_deg is None  # longitude unavailable: no centre shift either
    assert v.speed_mps is None  # 16383
    assert v.accel_mps2 == -14.0 and v.length_m == 100.0 and v.width_m == 0.1
    assert v.drive_direction is DriveDirection.BACKWARD
    assert unix_to_timestamp_its(v.generation_time_s) % 65536 == 65535
    # Vector 2 says protocolVersion 2 but is laid out as 1.3.2: by its version it does not decode.
    m2 = frames["message2_basicVehicleHF_with_cenDsrcTollingZone"]
    with pytest.raises(V2xDecodeError):
        from_etsi_cam(m2, T0_S, check_message_id=False)
    assert from_etsi_cam(m2, T0_S, schema=EtsiCamSchema.CAM_1_3_2, check_message_id=False)
    rsu = frames["message3_rsuHF"]
    with pytest.raises(V2xDecodeError) as err:
        from_etsi_cam(rsu, T0_S, schema=EtsiCamSchema.CAM_1_3_2, check_message_id=False)
    assert err.value.reason is DecodeReason.NOT_A_VEHICLE


def test_receiver_takes_real_cams_next_to_ours(real: dict[str, bytes]) -> None:
    v1, v2 = real["vanetza_issue_201"], real["pycrate_issue_156"]
    rx = V2vReceiver()
    near_v1 = GeoPoint(52.17, 5.39)
    # Received 50 ms after generation (a CAM's time is only known modulo 65.536 s).
    t1 = from_etsi_cam(v1, T0_S).generation_time_s + 0.05
    state = rx.receive(v1, t1, near_v1)
    assert state is not None and state.station_id == 78880133
    # The other CAM lies in Spain: out of range of a receiver in the Netherlands.
    t2 = from_etsi_cam(v2, T0_S).generation_time_s + 0.05
    assert rx.check(v2, t2, near_v1).reason == "out_of_range"
    # Seen 20 s after generation it is too old (the nearest-instant resolution keeps the 20 s).
    assert rx.check(v1, t1 + 20.0, near_v1).reason == "too_old"
    # Ours beside them, from a car near the first.
    ours = encode(VehicleState(5, t1, 52.1698, 5.3904, 0.0, 10.0, 0.0, 0.0, 4.5, 1.8))
    assert rx.receive(ours, t1 + 0.01, near_v1) is not None
    assert rx.received == rx.accepted + sum(rx.rejected.values()) == 4


def test_decode_dispatches_real_cams_and_ours_alike(real: dict[str, bytes]) -> None:
    cam = real["vanetza_issue_201"]
    state = decode(cam, T0_S)
    assert isinstance(state, VehicleState) and state.station_id == 78880133
    assert state == from_etsi_cam(cam, T0_S)


def test_missing_schemas_are_reported_with_where_we_looked(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("BYWIRE_ETSI_ASN1_DIR", str(tmp_path))
    with pytest.raises(EtsiSchemaMissing) as err:
        etsi_asn1_dir()
    assert str(tmp_path) in str(err.value) and "BYWIRE_ETSI_ASN1_DIR" in str(err.value)
    # Only release 2 (and an explicit directory) needs the shared files; the shipped ones do not.
    with pytest.raises(EtsiSchemaMissing):
        compiled_etsi_spec(EtsiCamSchema.CAM_2_3_1)
    assert compiled_etsi_spec(EtsiCamSchema.CAM_1_4_1) is not None
    monkeypatch.setenv("BYWIRE_ETSI_ASN1_DIR", str(DATA_DIR))
    assert etsi_asn1_dir() == DATA_DIR

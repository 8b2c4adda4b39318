"""`bywire v2x encode|decode`: a vehicle state in SI units to the exact bytes we broadcast, and any message
we receive back to JSON in the same units; bad input named by file and field."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bywire.protocol.v2x import v2x_cli
from bywire.protocol.v2x.codec import SpeedLimit, VehicleState
from bywire.protocol.v2x.dsrc import RoadMap
from bywire.protocol.v2x.iclcm import ControllerType, CooperativeState
from bywire.protocol.v2x.wire import encode

T0_S = 1_700_000_000.25
STATE = {
    "station_id": 42,
    "time_unix_s": T0_S,
    "lat_deg": 49.0123456,
    "lon_deg": 8.4123456,
    "heading_rad": 0.5,
    "speed_mps": 13.9,
    "yaw_rate_radps": 0.02,
    "accel_mps2": -0.8,
    "length_m": 4.77,
    "width_m": 1.82,
}


def test_encode_writes_the_bytes_we_broadcast_and_decode_reads_them_back(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    src, out = tmp_path / "state.json", tmp_path / "cam.bin"
    src.write_text(json.dumps(STATE))
    assert v2x_cli.run(["encode", str(src), "-o", str(out)]) == 0
    expected = VehicleState(42, T0_S, 49.0123456, 8.4123456, 0.5, 13.9, 0.02, -0.8, 4.77, 1.82)
    assert out.read_bytes() == encode(expected)
    capsys.readouterr()
    assert v2x_cli.run(["decode", str(out), "--time", str(T0_S + 0.1)]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["message"] == "CAM" and doc["station_id"] == 42
    assert doc["time_unix_s"] == pytest.approx(T0_S, abs=1e-3)
    assert doc["speed_mps"] == 13.9 and doc["accel_mps2"] == -0.8
    assert doc["lat_deg"] == pytest.approx(49.0123456, abs=2e-7)
    assert doc["length_m"] == 4.8 and doc["width_m"] == 1.8  # the CDD's 0.1 m
    # The decoded JSON encodes again to the same bytes (at its resolution).
    again = tmp_path / "again.json"
    again.write_text(json.dumps(doc))
    assert v2x_cli.run(["encode", str(again), "-o", str(tmp_path / "again.bin")]) == 0
    assert (tmp_path / "again.bin").read_bytes() == out.read_bytes()


def test_decode_prints_every_kind_we_receive(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    for msg, name in (
        (CooperativeState(7, T0_S, ControllerType.CACC, -1.5, 0.6), "iCLCM"),
        (RoadMap(9, T0_S, speed_limits=(SpeedLimit(9, T0_S, 3, 49.0, 8.4, 25.0),)), "MAPEM"),
    ):
        f = tmp_path / f"{name}.bin"
        f.write_bytes(encode(msg))
        assert v2x_cli.run(["decode", str(f), "--time", str(T0_S)]) == 0
        doc = json.loads(capsys.readouterr().out)
        assert doc["message"] == name and doc["station_id"] == msg.station_id
    assert doc["speed_limits"][0]["limit_mps"] == 25.0


def test_bad_input_is_named(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({k: v for k, v in STATE.items() if k != "speed_mps"}))
    assert v2x_cli.run(["encode", str(bad), "-o", str(tmp_path / "x.bin")]) == 2
    assert f"{bad}: missing speed_mps" in capsys.readouterr().err
    bad.write_text(json.dumps(STATE | {"speed_mps": 200.0}))
    assert v2x_cli.run(["encode", str(bad), "-o", str(tmp_path / "x.bin")]) == 2
    assert "VehicleState.speed_mps" in capsys.readouterr().err
    bad.write_text('{"station_id": 1,\n "lat_deg": }')
    assert v2x_cli.run(["encode", str(bad), "-o", str(tmp_path / "x.bin")]) == 2
    assert "line 2" in capsys.readouterr().err
    garbage = tmp_path / "garbage.bin"
    garbage.write_bytes(b"\x02\x02\x00")
    assert v2x_cli.run(["decode", str(garbage)]) == 1
    assert "too_short" in capsys.readouterr().err

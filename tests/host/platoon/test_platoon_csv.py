"""Platoon CSV reader: every published header spelling (a synthetic file per layout, written here with
exactly that header), the shared real recordings read as before, the unknown-layout error, and a fuzz of
the reader with hostile CSV text."""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from shared_data import shared_data_dir

from bywire.host.platoon.platoon_csv import Platoon, PlatoonCsvError, load_platoon_csv
from bywire.host.platoon.platoon_layouts import LAYOUTS

N_ROWS = 300  # 30 s at 10 Hz: above the 20 s the reader needs
DT_S = 0.1
REPO = Path(__file__).resolve().parents[3]


def _speed(k: int, t_s: float) -> float:
    """Vehicle k's speed: a distinct sine per vehicle, so a mixed-up order shows."""
    return round(15.0 + k + math.sin(0.5 * t_s - 0.4 * k), 4)


def _accel(k: int, t_s: float) -> float:
    return round(0.5 * math.cos(0.5 * t_s - 0.4 * k), 4)


def _write(path: Path, lines: list[str]) -> Path:
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def _table(
    header: list[str], cell: Callable[[str, int, float], str], t0_s: float = 0.0, n: int = N_ROWS
) -> list[str]:
    """Header line and n rows; `cell(column, row, time)` spells each field."""
    lines = [",".join(header)]
    for r in range(n):
        t = t0_s + DT_S * r
        lines.append(",".join(cell(col, r, t) for col in header))
    return lines


def _assert_speeds(platoon: Platoon, keys: list[int], t0_s: float = 0.0) -> None:
    """The resampled speeds are the written ones, vehicle by vehicle in platoon order."""
    t = t0_s + platoon.time_s
    for vehicle, k in zip(platoon.vehicles, keys, strict=True):
        expected = np.array([_speed(k, ti) for ti in t])
        np.testing.assert_allclose(vehicle.speed_mps, expected, atol=1e-9, err_msg=vehicle.name)


# ------------------------------------------------------------------------------------------ OpenACC (JRC)


def _openacc_cell(col: str, r: int, t: float) -> str:
    m = re.fullmatch(r"([A-Za-z]+)(\d+)", col)
    if col == "Time":
        return f"{t:.1f}"
    assert m, col
    kind, k = m.group(1), int(m.group(2))
    if kind == "Speed":
        return f"{_speed(k, t)}"
    if kind == "Driver":
        return "ACC" if r % 50 else "Human"
    return f"{0.01 * r + k:.3f}"  # positions, spacings: not read, only present


def test_openacc_astazero_release(tmp_path: Path) -> None:
    """AstaZero: Lat, Lon, Alt, E, N, U per car, then every Driver<i>, then IVS<i>; metadata padded with
    commas; ACC flag 0 with ACC samples."""
    header = ["Time"]
    for k in (1, 2, 3):
        header += [f"{f}{k}" for f in ("Speed", "Lat", "Lon", "Alt", "E", "N", "U")]
    header += ["Driver1", "Driver2", "Driver3", "IVS1", "IVS2"]
    meta = [
        "Date,4,7,2019,,,,,,",
        "Vehicle_order,Audi (A8),Audi(A6),BMW(X5),,,,",
        "Number_of_vehicles,3,,,,,",
        "ACC,0,,,,,",
        "Distance_setting,none",
    ]
    p = load_platoon_csv(_write(tmp_path / "ASta_040719_platoon1.csv", meta + _table(header, _openacc_cell)))
    assert p.layout == "openacc_jrc"
    assert [v.name for v in p.vehicles] == ["1:Audi (A8)", "2:Audi(A6)", "3:BMW(X5)"]
    assert not any(v.accel_from_file for v in p.vehicles)
    _assert_speeds(p, [1, 2, 3])


def test_openacc_zalazone_release(tmp_path: Path) -> None:
    """ZalaZone: E, N, Lon, Lat, Alt; vehicle 3 listed but without columns; trailing commas on data
    rows; column names padded with blanks."""
    header = ["Time"]
    for k in (1, 2, 4):
        header += [f"{f}{k}" for f in ("Speed", "E", "N", "Lon", "Lat", "Alt")]
    header += ["IVS1", "IVS2"]
    lines = _table(header, _openacc_cell, t0_s=920.1)
    lines[0] = ", ".join(header)
    lines[1:] = [row + "," for row in lines[1:]]
    meta = ["Date,8,10,2019", "Vehicle_order,SMART,MERCEDES,TESLA,AUDI,", "Number_of_vehicles,4", "ACC,1"]
    p = load_platoon_csv(_write(tmp_path / "dynamic_part8.csv", [*meta, "Distance_setting,M", *lines]))
    assert p.layout == "openacc_jrc"
    assert [v.name for v in p.vehicles] == ["1:SMART", "2:MERCEDES", "4:AUDI"]
    _assert_speeds(p, [1, 2, 4], t0_s=920.1)


def test_openacc_vicolungo_and_casale_release(tmp_path: Path) -> None:
    """Vicolungo adds VE, VN, VU; Casale's leader has no Alt/U and only the follower a Driver column."""
    header = ["Time"]
    for k in (1, 2):
        header += [f"{f}{k}" for f in ("Speed", "Lat", "Lon", "Alt", "E", "N", "U", "VE", "VN", "VU")]
    header += ["IVS1", "Driver1", "Driver2"]
    meta = ["Date,26,2,2019", "Vehicle_order,A,B", "Number_of_vehicles,2", "ACC,2", "Distance_setting,"]
    p = load_platoon_csv(_write(tmp_path / "vico.csv", meta + _table(header, _openacc_cell)))
    assert (p.layout, [v.name for v in p.vehicles]) == ("openacc_jrc", ["1:A", "2:B"])
    _assert_speeds(p, [1, 2])
    header = ["Time", "Speed1", "Lat1", "Lon1", "E1", "N1"]
    header += ["Speed2", "Lat2", "Lon2", "Alt2", "E2", "N2", "U2", "IVS1", "Driver2"]
    meta = ["Date,27,10,2020", "Vehicle_order,Rexton,Hyundai", "Number_of_vehicles,2", "ACC,1"]
    p = load_platoon_csv(
        _write(tmp_path / "part3.csv", [*meta, "Distance_setting,min", *_table(header, _openacc_cell)])
    )
    assert [v.name for v in p.vehicles] == ["1:Rexton", "2:Hyundai"]
    _assert_speeds(p, [1, 2])


@pytest.mark.parametrize("speed_column", ["Speed{}", "Speed_{}"])
def test_openacc_cut_without_metadata(tmp_path: Path, speed_column: str) -> None:
    """The AstaZero cuts: `Time,Speed_1..` (OpenACC_trajectory_1) and `Time,Speed1..` (_2)."""
    header = ["Time", *(speed_column.format(k) for k in (1, 2, 3, 4, 5))]

    def cell(col: str, r: int, t: float) -> str:
        return repr(t) if col == "Time" else f"{_speed(int(col.rsplit('d', 1)[1].lstrip('_')), t)}"

    p = load_platoon_csv(_write(tmp_path / "OpenACC_trajectory.csv", _table(header, cell)))
    assert (p.layout, [v.name for v in p.vehicles]) == ("openacc_cut", ["1", "2", "3", "4", "5"])
    _assert_speeds(p, [1, 2, 3, 4, 5])


def test_openacc_header_missing_after_metadata(tmp_path: Path) -> None:
    lines = ["Date,8,10,2019", "Vehicle_order,A,B", *[f"Comment,{k}" for k in range(12)]]
    with pytest.raises(PlatoonCsvError, match=r"m\.csv:11: expected the OpenACC header 'Time,Speed1,"):
        load_platoon_csv(_write(tmp_path / "m.csv", lines))
    lines = ["Date,8,10,2019", "Vehicle_order,A,B", "Time,E1,N1", "0,1,2"]
    with pytest.raises(PlatoonCsvError, match=r"n\.csv:3: OpenACC header has no 'Speed<i>' column"):
        load_platoon_csv(_write(tmp_path / "n.csv", lines))


# ------------------------------------------------------------------------------------------------- CARMA

_COLOURS = ("BLACK", "GREEN", "GREY", "SILVER", "WHITE")


def test_carma2_licit_cut(tmp_path: Path) -> None:
    vehicles = ["leader", "follower1", "follower2", "follower3", "follower4"]
    header = ["Date", "Heure", "Time"]
    for v in vehicles:
        header += [f"{v}_CARMA_mode", f"{v}_avg_speed_driven_wheels", f"{v}_GPS_speed", f"{v}_acceleration"]

    def cell(col: str, r: int, t: float) -> str:
        if col in ("Date", "Heure"):
            return "17/07/2018" if col == "Date" else "13:44:00"
        if col == "Time":
            return f"{t:.1f}"
        k = vehicles.index(col.split("_", 1)[0])
        if col.endswith("_avg_speed_driven_wheels"):
            return f"{_speed(k, t)}"
        return f"{_accel(k, t)}" if col.endswith("_acceleration") else "2.0"

    p = load_platoon_csv(_write(tmp_path / "data5.csv", _table(header, cell)))
    assert (p.layout, [v.name for v in p.vehicles]) == ("carma2_licit", vehicles)
    assert all(v.accel_from_file for v in p.vehicles)
    _assert_speeds(p, [0, 1, 2, 3, 4])
    np.testing.assert_allclose(p.vehicles[2].accel_mps2, [_accel(2, t) for t in p.time_s], atol=1e-9)


def _carma2_usdot(path: Path, runs: dict[int, int]) -> Path:
    """Runs (RunNo -> rows) one after the other; speeds keyed by the colour's place in BLACK..WHITE."""
    header = ["LocationDateTime", "RunNo", "Elapsed_Time"]
    for c in _COLOURS:
        header += [f"veh_color_{c}", f"vehspdavgdrvn_srx_{c}", f"flrrtrk1range_srx_{c}"]
        header += [f"p29_actual_vehicle_acceleration_{c}"]
    lines = [",".join(header)]
    for run, n in runs.items():
        for r in range(n):
            t = DT_S * r
            cells = {"LocationDateTime": "2018-07-17T13:44:00", "RunNo": f"{run}", "Elapsed_Time": f"{t:.1f}"}
            for k, c in enumerate(_COLOURS):
                cells |= {f"veh_color_{c}": c, f"vehspdavgdrvn_srx_{c}": f"{_speed(k, t)}"}
                cells |= {
                    f"flrrtrk1range_srx_{c}": "25.0",
                    f"p29_actual_vehicle_acceleration_{c}": f"{_accel(k, t)}",
                }
            lines.append(",".join(cells[h] for h in header))
    return _write(path, lines)


def test_carma2_as_published(tmp_path: Path) -> None:
    path = _carma2_usdot(tmp_path / "carma2.csv", {5: N_ROWS, 7: 40, 10: N_ROWS})
    p = load_platoon_csv(path, run="10")
    assert (p.layout, [v.name for v in p.vehicles]) == ("carma2_usdot", list(_COLOURS))
    assert p.notes[0] == "run 10" and "file has none" in p.notes[1]
    assert all(v.accel_from_file for v in p.vehicles)
    _assert_speeds(p, [0, 1, 2, 3, 4])
    with pytest.raises(PlatoonCsvError, match=r"'RunNo' holds 3 runs \(5, 7, 10\): give the run"):
        load_platoon_csv(path)
    with pytest.raises(
        PlatoonCsvError, match=r"run 7: its platoon order is not in the file .* 5, 6, 9, 10, 13"
    ):
        load_platoon_csv(path, run="7")
    with pytest.raises(PlatoonCsvError, match=r"has no run '8'"):
        load_platoon_csv(path, run="8")
    one_run = _carma2_usdot(tmp_path / "run6.csv", {6: N_ROWS})
    assert load_platoon_csv(one_run).notes[0] == "run 6"


def test_carma1_as_published(tmp_path: Path) -> None:
    """CARMA 1: colour suffixes, 20 Hz, the order of run 30 is BLACK, WHITE, GREY, GREEN, SILVER."""
    suffixes = ("bl", "grn", "wt", "ag", "gry")
    header = ["Run", "bin_utc_time_formatted", "elapsed_time (s)"]
    for s in suffixes:
        header += [f"speed_CACC-{s}", f"distToPVeh_CACC-{s}", f"velocity_fwd_PINPOINT-{s}"]
    lines = [",".join(header)]
    for r in range(2 * N_ROWS):
        t = 0.05 * r
        cells = ["30", "2016-08-02 10:00:00", f"{t:.2f}"]
        for k, _ in enumerate(suffixes):
            cells += [f"{_speed(k, t)}", "20.0", ""]
        lines.append(",".join(cells))
    p = load_platoon_csv(_write(tmp_path / "poc.csv", lines))
    assert (p.layout, [v.name for v in p.vehicles]) == ("carma1_usdot", ["bl", "wt", "gry", "grn", "ag"])
    assert p.sample_period_s == pytest.approx(0.05)
    _assert_speeds(p, [0, 2, 4, 1, 3])


def test_carma1_licit_cut(tmp_path: Path) -> None:
    vehicles = ["leader", "follower1", "follower2", "follower3", "follower4"]
    header = ["bin_utc_time_formatted", "elapsed_time (s)"]
    header += [f"speed_CACC_{v}" for v in vehicles] + [f"distToPVeh_CACC_{v}" for v in vehicles[1:]]

    def cell(col: str, r: int, t: float) -> str:
        if col == "elapsed_time (s)":
            return f"{t:.1f}"
        if col.startswith("speed_CACC_"):
            return f"{_speed(vehicles.index(col.removeprefix('speed_CACC_')), t)}"
        return "x" if col.startswith("bin") else "18.0"

    p = load_platoon_csv(_write(tmp_path / "poc_cut.csv", _table(header, cell)))
    assert (p.layout, [v.name for v in p.vehicles]) == ("carma1_licit", vehicles)
    _assert_speeds(p, [0, 1, 2, 3, 4])


def test_missing_acceleration_is_differentiated_and_said(tmp_path: Path) -> None:
    header = ["Time", "leader_avg_speed_driven_wheels", "follower1_avg_speed_driven_wheels"]
    header += ["leader_acceleration"]

    def cell(col: str, r: int, t: float) -> str:
        return f"{t:.1f}" if col == "Time" else f"{_speed(0 if 'leader' in col else 1, t)}"

    p = load_platoon_csv(_write(tmp_path / "c.csv", _table(header, cell)))
    assert not any(v.accel_from_file for v in p.vehicles)
    assert any("no follower1_acceleration" in n for n in p.notes)


# ------------------------------------------------------------------------------------------ errors


def test_unknown_header_names_every_expected_layout(tmp_path: Path) -> None:
    path = _write(tmp_path / "u.csv", ["time_s,v_leader,v_follower", "0,1,2"])
    with pytest.raises(PlatoonCsvError) as err:
        load_platoon_csv(path)
    message = str(err.value)
    assert message.startswith(f"{path}:1: unknown platoon CSV layout (expected one of: ")
    for layout in LAYOUTS:
        assert f"{layout.title} {layout.signature}" in message
    assert message.endswith("got 'time_s,v_leader,v_follower'")


def test_a_run_for_a_file_of_one_run_is_refused(tmp_path: Path) -> None:
    header = ["Time", "Speed1", "Speed2"]
    path = _write(tmp_path / "c.csv", _table(header, _openacc_cell))
    with pytest.raises(
        PlatoonCsvError, match=r"c\.csv: openacc_cut files hold one run each; run='3' does not apply"
    ):
        load_platoon_csv(path, run="3")


@pytest.mark.parametrize(
    ("row", "message"),
    [
        ("1.0,inf,20", r"x\.csv:12: column 'Speed1': not a finite number: 'inf'"),
        ("nan,20,20", r"x\.csv:12: column 'Time': not a number: 'nan'"),
        (",20,20", r"x\.csv:12: column 'Time': empty"),
    ],
)
def test_bad_cells_name_line_and_column(tmp_path: Path, row: str, message: str) -> None:
    lines = _table(["Time", "Speed1", "Speed2"], _openacc_cell)
    lines.insert(11, row)
    with pytest.raises(PlatoonCsvError, match=message):
        load_platoon_csv(_write(tmp_path / "x.csv", lines))


def test_duplicate_column_and_irregular_time(tmp_path: Path) -> None:
    dup = _write(tmp_path / "d.csv", _table(["Time", "Speed1", "Speed2", "Speed1"], _openacc_cell))
    with pytest.raises(
        PlatoonCsvError, match=r"d\.csv:1: header names column 'Speed1' 2 times \(fields 2, 4\)"
    ):
        load_platoon_csv(dup)
    lines = ["Time,Speed1,Speed2", *(f"{k * 1e-9:.9f},20,20" for k in range(5)), "1000000,20,20"]
    with pytest.raises(PlatoonCsvError, match=r"i\.csv: irregular time column"):
        load_platoon_csv(_write(tmp_path / "i.csv", lines))


def test_not_text(tmp_path: Path) -> None:
    path = tmp_path / "b.csv"
    path.write_bytes(b"Time,Speed1\n\xff\xfe\x00garbage\n")
    with pytest.raises(PlatoonCsvError, match=r"b\.csv: not UTF-8 text"):
        load_platoon_csv(path)


# ------------------------------------------------------------------------------------------ fuzz

_TOKENS = st.sampled_from(
    [
        "Time",
        "Speed1",
        "Speed_2",
        "Date",
        "Vehicle_order",
        "RunNo",
        "Elapsed_Time",
        "vehspdavgdrvn_srx_BLACK",
        "leader_avg_speed_driven_wheels",
        "follower1_acceleration",
        "Run",
        "elapsed_time (s)",
        "speed_CACC-bl",
        "0",
        "0.1",
        "-1e308",
        "1e309",
        "nan",
        "",
        " ",
        '"',
        '"a,b"',
        "\x00",
        "é",
        "9" * 40,
    ]
)
_LINE = st.lists(st.one_of(_TOKENS, st.text(max_size=6)), max_size=8).map(",".join)


def _prefix() -> st.SearchStrategy[list[str]]:
    """A valid start of some layout, so the fuzz gets past detection into the table and the grid."""
    return st.sampled_from(
        [
            [],
            ["Time,Speed1,Speed2"],
            ["Time,Speed_1,Speed_2"],
            ["Date,1,1,2020", "Vehicle_order,A,B", "Time,Speed1,Speed2"],
            ["RunNo,Elapsed_Time,vehspdavgdrvn_srx_BLACK,vehspdavgdrvn_srx_GREEN"],
            ["Time,leader_avg_speed_driven_wheels,follower1_avg_speed_driven_wheels,leader_acceleration"],
        ]
    )


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(prefix=_prefix(), lines=st.lists(_LINE, max_size=40), run=st.sampled_from([None, "5", "x"]))
def test_fuzz_hostile_csv_text(tmp_path: Path, prefix: list[str], lines: list[str], run: str | None) -> None:
    path = tmp_path / "f.csv"
    path.write_text("\n".join(prefix + lines), encoding="utf-8", errors="surrogatepass")
    try:
        platoon = load_platoon_csv(path, run=run)
    except PlatoonCsvError:
        return
    assert len(platoon.vehicles) >= 2
    assert all(np.isfinite(v.speed_mps).all() for v in platoon.vehicles)


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cells=st.lists(st.sampled_from(["", "x", "inf", "1e5", "-0", "20", "nan"]), min_size=1, max_size=20))
def test_fuzz_garbled_cells_in_a_valid_file(tmp_path: Path, cells: list[str]) -> None:
    """A valid recording with a few cells replaced: read, or refused by the reader's own error."""
    lines = _table(["Time", "Speed1", "Speed2"], _openacc_cell)
    for k, text in enumerate(cells):
        r = 1 + (37 * k) % N_ROWS
        fields = lines[r].split(",")
        fields[k % 3] = text
        lines[r] = ",".join(fields)
    path = _write(tmp_path / "g.csv", lines)
    try:
        platoon = load_platoon_csv(path)
    except PlatoonCsvError as exc:
        assert str(exc).startswith(f"{path}"), exc  # says which file (and line, where one is to blame)
        return
    assert len(platoon.vehicles) == 2
    assert all(np.isfinite(v.speed_mps).all() and np.isfinite(v.accel_mps2).all() for v in platoon.vehicles)


# ------------------------------------------------------------------------------------------ shared data

DATA_DIR = shared_data_dir() / "platoon"

# What the reader returned for the shared recordings before the layout table came in (same pipeline):
# layout, samples, vehicle names, notes, sum of all speeds and of all accelerations, leader's middle speed.
_BEFORE = {
    "carma_fhwa_2018/data5.csv": (
        "carma2_licit",
        4000,
        ["leader", "follower1", "follower2", "follower3", "follower4"],
        ("5 breaks in time order, rows sorted back (first at line 429)",),
        231029.80287923256,
        886.1500000000492,
        19.45314056248569,
    ),
    "openacc_astazero/OpenACC_trajectory_1.csv": (
        "openacc_cut",
        300,
        ["1", "2", "3", "4", "5"],
        (),
        29142.04368037,
        208.24679742710705,
        19.05363636,
    ),
    "openacc_zalazone/medium_setting__dynamic_part8.csv": (
        "openacc_jrc",
        4448,
        ["1:SMART_TARGET", "2:MERCEDES_GLE450", "3:TESLA_MODELX", "4:TESLA_MODELS", "5:AUDI_E_TRON"],
        (),
        180255.52048528817,
        -13.957078187507049,
        8.164181129230382,
    ),
    "openacc_zalazone/no_ACC__handling_part40.csv": (
        "openacc_jrc",
        2698,
        [
            "2:JAGUAR_I_PACE",
            "3:BMW_I3",
            "4:MERCEDES_GLE450",
            "5:TESLA_MODELX",
            "6:TESLA_MODELS",
            "8:AUDI_E_TRON",
            "10:MAZDA_3",
        ],
        (
            "vehicle 2:JAGUAR_I_PACE: 1 samples in gaps > 1.0 s",
            "vehicle 3:BMW_I3: 83 samples in gaps > 1.0 s",
            "vehicle 4:MERCEDES_GLE450: 2 samples in gaps > 1.0 s",
            "vehicle 5:TESLA_MODELX: 1 samples in gaps > 1.0 s",
            "vehicle 6:TESLA_MODELS: 1 samples in gaps > 1.0 s",
            "vehicle 8:AUDI_E_TRON: 1 samples in gaps > 1.0 s",
            "vehicle 10:MAZDA_3: 2 samples in gaps > 1.0 s",
            "record cut to 8.2-277.9 s (longest stretch without a gap > 1.0 s in any vehicle)",
        ),
        256397.20566839376,
        -41.101254205684356,
        15.657232924514595,
    ),
    "openacc_zalazone/short_setting__dynamic_part10.csv": (
        "openacc_jrc",
        7578,
        ["1:SMART_TARGET", "2:MERCEDES_GLE450", "3:TESLA_MODELX", "4:AUDI_E_TRON"],
        (),
        333392.46289500466,
        -6.941858772702769,
        11.125759597669896,
    ),
}


@pytest.mark.parametrize("name", sorted(_BEFORE))
def test_shared_recordings_read_as_before(name: str) -> None:
    path = DATA_DIR / name
    if not path.exists():
        pytest.skip(f"shared platoon recording {path} is absent (read in place, never copied)")
    layout, n, names, notes, speed_sum, accel_sum, leader_mid = _BEFORE[name]
    p = load_platoon_csv(path)
    assert (p.layout, p.time_s.size, [v.name for v in p.vehicles], p.notes) == (layout, n, names, notes)
    assert float(np.concatenate([v.speed_mps for v in p.vehicles]).sum()) == pytest.approx(
        speed_sum, rel=1e-12
    )
    assert float(np.concatenate([v.accel_mps2 for v in p.vehicles]).sum()) == pytest.approx(
        accel_sum, rel=1e-9, abs=1e-9
    )
    assert float(p.vehicles[0].speed_mps[n // 2]) == pytest.approx(leader_mid, rel=1e-12)


def test_guide_lists_every_layout() -> None:
    guide = (REPO / "docs" / "platoon_files.md").read_text(encoding="utf-8")
    for layout in LAYOUTS:
        assert f"`{layout.name}`" in guide, layout.name
        assert layout.time_column in guide, layout.name

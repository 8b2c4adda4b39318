"""String-stability estimator (cooperative driving): known-answer synthetic chains, CSV layouts and errors,
CLI contract JSON, and the shared real recordings (read in place from ../shared/data, never copied)."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
import pytest
from shared_data import shared_data_dir

from bywire.host.platoon import platoon_cli
from bywire.host.platoon.string_stability import (
    FloatArray,
    Platoon,
    PlatoonCsvError,
    SignalName,
    band_limited_noise,
    cth_follower_tf,
    hinf_norm,
    linear_chain_platoon,
    load_platoon_csv,
    string_stability,
)

DATA_DIR = shared_data_dir() / "platoon"
REAL_CSVS = sorted(DATA_DIR.glob("*/*.csv")) if DATA_DIR.is_dir() else []
DT_S = 0.1
# Welch with 0.02 Hz bins and a Hann window smooths |H| a little around a peak; 3 % covers that plus the
# random error of ~45 averaged segments (coherence ~1, so the H1 variance is tiny).
REL_TOL = 0.03

# PD spacing control with a 0.2 s actuator lag: kp = 1 1/s², kd = 1.5 1/s.
KP_PER_S2, KD_PER_S, LAG_S = 1.0, 1.5, 0.2


def _chain(headway_s: float, speed_noise_mps: float = 0.0) -> tuple[tuple[FloatArray, FloatArray], Platoon]:
    num, den = cth_follower_tf(headway_s, KP_PER_S2, KD_PER_S, LAG_S)
    leader = band_limited_noise(1200.0, DT_S, (0.02, 1.0), seed=1)
    return (num, den), linear_chain_platoon(
        leader, DT_S, num, den, 4, speed_noise_mps=speed_noise_mps, seed=2
    )


@pytest.mark.parametrize("speed_noise_mps", [0.0, 0.05])
def test_string_stable_chain_recovers_band_peak(speed_noise_mps: float) -> None:
    # Headway 1.5 s: |H| falls monotonically from 1 at DC (H-inf norm exactly 1, reached at f = 0), so over
    # the excited band the true peak is |H| at the band's low edge, below 1.
    (num, den), platoon = _chain(1.5, speed_noise_mps)
    assert hinf_norm(num, den)[0] == pytest.approx(1.0, abs=1e-3)
    result = string_stability(platoon)
    true_peak = hinf_norm(num, den, result.band_hz)[0]
    assert true_peak < 1.0
    for pair in result.pairs:
        assert pair.ratio == pytest.approx(true_peak, rel=REL_TOL)
    assert result.string_stability < 1.0


@pytest.mark.parametrize("speed_noise_mps", [0.0, 0.05])
def test_string_unstable_chain_recovers_hinf_norm(speed_noise_mps: float) -> None:
    # Headway 0.2 s: |H| peaks at 1.23 near 0.12 Hz, inside the excited band.
    (num, den), platoon = _chain(0.2, speed_noise_mps)
    norm, f_peak_hz = hinf_norm(num, den)
    assert norm > 1.2
    result = string_stability(platoon)
    assert result.band_hz[0] < f_peak_hz < result.band_hz[1]
    for pair in result.pairs:
        assert pair.ratio == pytest.approx(norm, rel=REL_TOL)
        assert pair.peak_hz == pytest.approx(f_peak_hz, abs=0.03)
    assert result.string_stability > 1.0
    # The speed ratio measures the same transfer function.
    assert string_stability(platoon, "speed").string_stability == pytest.approx(norm, rel=REL_TOL)


def test_explicit_band() -> None:
    (num, den), platoon = _chain(0.2)
    result = string_stability(platoon, band_hz=(0.4, 0.8))
    assert result.band_hz == (0.4, 0.8)
    assert result.string_stability == pytest.approx(hinf_norm(num, den, (0.4, 0.8))[0], rel=REL_TOL)
    with pytest.raises(ValueError, match="low edge"):
        string_stability(platoon, band_hz=(0.8, 0.4))


# ------------------------------------------------------------------------------------------- CSV layouts


def _astazero_csv(path: Path, n: int = 400, extra: str = "") -> Path:
    t = DT_S * np.arange(n)
    lines = ["Time,Speed_1,Speed_2,Speed_3"]
    for k, tk in enumerate(t):
        lines.append(
            f"{tk:.1f},{20 + np.sin(tk):.4f},{20 + np.sin(tk - 0.3):.4f},{20 + np.sin(tk - 0.6):.4f}"
        )
        if k == 10 and extra:
            lines.append(extra)
    path.write_text("\n".join(lines) + "\n")
    return path


def _zalazone_csv(path: Path, n: int = 400, gap: tuple[int, int] | None = None) -> Path:
    meta = ["Date,8,10,2019", "Vehicle_order,A,B,", "Number_of_vehicles,2", "ACC,1", "Distance_setting,S"]
    header = "Time,Speed1,E1,N1,Lon1,Lat1,Alt1,Speed2,E2,N2,Lon2,Lat2,Alt2,IVS1"
    lines = [*meta, header]
    for k in range(n):
        t = 100.0 + DT_S * (k + 1)
        v2 = "" if gap and gap[0] <= k < gap[1] else f"{10 + np.sin(t - 0.5):.4f}"
        lines.append(f"{t:.1f},{10 + np.sin(t):.4f},0,0,0,0,0,{v2},0,0,0,0,0,12.0")
    path.write_text("\n".join(lines) + "\n")
    return path


def test_layout_detection(tmp_path: Path) -> None:
    p = load_platoon_csv(_astazero_csv(tmp_path / "a.csv"))
    assert p.layout == "openacc_cut"
    assert [v.name for v in p.vehicles] == ["1", "2", "3"]
    assert p.sample_period_s == pytest.approx(DT_S)
    # Differentiated acceleration of 20 + sin(t) is cos(t) (the 2 Hz low-pass barely touches 0.16 Hz).
    assert np.allclose(p.vehicles[0].accel_mps2[20:-20], np.cos(p.time_s[20:-20]), atol=0.02)
    z = load_platoon_csv(_zalazone_csv(tmp_path / "z.csv"))
    assert z.layout == "openacc_jrc"
    assert [v.name for v in z.vehicles] == ["1:A", "2:B"]
    assert z.time_s[0] == 0.0


def test_short_gap_interpolated_long_gap_cuts(tmp_path: Path) -> None:
    short = load_platoon_csv(_zalazone_csv(tmp_path / "s.csv", gap=(100, 105)))
    assert short.time_s.size == 400 and not short.notes
    assert np.isfinite(short.vehicles[1].speed_mps).all()
    long = load_platoon_csv(_zalazone_csv(tmp_path / "l.csv", n=600, gap=(100, 130)))
    assert long.time_s.size < 600 - 100 and any("record cut" in n for n in long.notes)
    with pytest.raises(PlatoonCsvError, match="without gaps"):
        load_platoon_csv(_zalazone_csv(tmp_path / "x.csv", n=400, gap=(100, 330)))


def test_unknown_layout(tmp_path: Path) -> None:
    path = tmp_path / "u.csv"
    path.write_text("foo,bar\n1,2\n")
    with pytest.raises(PlatoonCsvError, match=r"u\.csv:1: unknown platoon CSV layout"):
        load_platoon_csv(path)


def test_garbled_value_names_line_and_column(tmp_path: Path) -> None:
    path = _astazero_csv(tmp_path / "g.csv", extra="1.15,20.0,abc,20.0")
    with pytest.raises(PlatoonCsvError, match=r"g\.csv:13: column 'Speed_2': not a number: 'abc'"):
        load_platoon_csv(path)


def test_truncated_row(tmp_path: Path) -> None:
    path = _astazero_csv(tmp_path / "t.csv")
    path.write_text(path.read_text() + "40.0,20.1\n")
    with pytest.raises(PlatoonCsvError, match=r"t\.csv:402: 2 fields, header has 4 .*'Speed_2'"):
        load_platoon_csv(path)


def test_repeated_time_stamp(tmp_path: Path) -> None:
    path = _astazero_csv(tmp_path / "d.csv", extra="0.5,20.0,20.0,20.0")
    with pytest.raises(PlatoonCsvError, match=r"d\.csv:13: column 'Time': 0.5 repeats"):
        load_platoon_csv(path)


# ------------------------------------------------------------------------------------------- CLI


def _args(csv: Path, **kw: object) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    platoon_cli.add_arguments(parser)
    argv = [str(csv)]
    for key, value in kw.items():
        argv += [f"--{key}", *(str(v) for v in (value if isinstance(value, tuple) else (value,)))]
    return parser.parse_args(argv)


def test_cli_contract_json(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    csv = _zalazone_csv(tmp_path / "z.csv", n=600)
    out = tmp_path / "r.json"
    assert platoon_cli.main(_args(csv, json=out, plot=tmp_path / "r.png")) == 0
    doc = json.loads(out.read_text())
    assert {"string_stability", "pairs", "band_hz"} <= doc.keys()
    assert doc["pairs"][0].keys() >= {"leader", "follower", "ratio"}
    assert doc["pairs"][0]["leader"] == "1:A" and doc["pairs"][0]["follower"] == "2:B"
    assert doc["string_stability"] == max(p["ratio"] for p in doc["pairs"])
    assert len(doc["band_hz"]) == 2
    assert (tmp_path / "r.png").stat().st_size > 0
    assert "string_stability" in capsys.readouterr().out
    # Explicit band and speed signal pass through.
    assert platoon_cli.main(_args(csv, json=out, signal="speed", band=(0.1, 0.3))) == 0
    doc = json.loads(out.read_text())
    assert doc["band_hz"] == [0.1, 0.3] and doc["signal"] == "speed"


def test_cli_reports_bad_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "u.csv"
    path.write_text("foo\n")
    assert platoon_cli.main(_args(path)) == 2
    assert "unknown platoon CSV layout" in capsys.readouterr().err


# ------------------------------------------------------------------------------------------- real data


@pytest.mark.skipif(not REAL_CSVS, reason=f"shared platoon recordings not found under {DATA_DIR}")
@pytest.mark.parametrize("csv", REAL_CSVS, ids=lambda p: p.name)
def test_real_recording(csv: Path) -> None:
    platoon = load_platoon_csv(csv)
    assert len(platoon.vehicles) >= 4
    signals: tuple[SignalName, ...] = ("accel", "speed")
    for signal in signals:
        result = string_stability(platoon, signal)
        assert len(result.pairs) == len(platoon.vehicles) - 1
        assert all(math.isfinite(p.ratio) and p.ratio > 0 for p in result.pairs)
        ratios = ", ".join(
            f"{p.leader}->{p.follower} {p.ratio:.2f} (coh {p.coherence_at_peak:.2f})" for p in result.pairs
        )
        print(
            f"{csv.name} [{signal}] band {result.band_hz[0]:.3f}-{result.band_hz[1]:.3f} Hz: "
            f"worst {result.string_stability:.2f}; {ratios}; notes {platoon.notes}"
        )


def test_the_contract_command_runs_as_a_user_runs_it(tmp_path: Path) -> None:
    """`bywire platoon string-stability CSV --json FILE` (its JSON contract)."""
    import subprocess
    import sys

    csv = DATA_DIR / "carma_fhwa_2018" / "data5.csv"
    if not csv.exists():
        pytest.skip(f"{csv} is not here: the shared platoon recordings are absent")
    out = tmp_path / "ss.json"
    proc = subprocess.run(
        [sys.executable, "-m", "bywire", "platoon", "string-stability", str(csv), "--json", str(out)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(out.read_text())
    assert {"string_stability", "pairs", "band_hz"} <= set(doc)
    assert {"leader", "follower", "ratio"} <= set(doc["pairs"][0])
